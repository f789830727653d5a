"""A deployment session: fleet up (starting the hardware twin when the fleet says so), runner, recording.

Everything opened here is closed on every exit path: robots get zero velocity, the MCAP is
finalized, the transport and the twin process are shut down.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from pipeline.core.episode import EpisodeResult
from pipeline.core.observation import ObservationLayout
from pipeline.core.scenario import Scenario, load_scenario
from pipeline.errors import PolicyMismatch
from pipeline.policy.runtime import PolicyRuntime
from pipeline.record.session import SessionLog, dumps, session_metadata
from pipeline.ros.clock import Clock, ScaledClock, WallClock
from pipeline.ros.deploy import DeployRunner, FleetNotReady
from pipeline.ros.fleet import Fleet
from pipeline.ros.transport import open_transport
from pipeline.settings import to_mapping

TWIN_START_TIMEOUT_S = 60.0
SWITCH_INTERVAL_S = 0.00005


@dataclass(frozen=True)
class DeployRequest:
    """One deployment session's settings beyond the fleet file."""

    episodes: int
    seed: int
    recording: Path
    time_scale: float = 0.0
    """Twin time scale; 0 keeps the fleet file's."""
    profile: str = ""
    """Twin reality profile; empty keeps the fleet file's."""
    chunk_size_bytes: int = 1_048_576
    params_text: str = ""
    progress: bool = True


class TwinProcess:
    """The hardware twin as a child process; its output is kept for error messages."""

    def __init__(self, fleet_source: str, profile: str, time_scale: float, seed: int, extra: list[str] | None = None):
        cmd = [sys.executable, "-m", "pipeline.twin", "--fleet", fleet_source, "--profile", profile]
        cmd += ["--time-scale", repr(time_scale), "--seed", str(seed), *(extra or [])]
        self.proc = subprocess.Popen(
            cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True
        )
        self.lines: deque[str] = deque(maxlen=50)
        self.ready = threading.Event()
        threading.Thread(target=self._pump, args=(self.proc.stdout,), daemon=True).start()
        threading.Thread(target=self._pump, args=(self.proc.stderr,), daemon=True).start()

    def _pump(self, stream: object) -> None:
        for line in stream:  # type: ignore[attr-defined]
            self.lines.append(line.rstrip())
            if line.startswith("twin: ready"):
                self.ready.set()

    def wait_ready(self, timeout_s: float) -> None:
        deadline = time.monotonic() + timeout_s
        while not self.ready.wait(0.05):
            if self.proc.poll() is not None or time.monotonic() > deadline:
                problem = self.problem() or f"it did not report ready within {timeout_s:g} s"
                raise FleetNotReady(f"the hardware twin did not start: {problem}")

    def problem(self) -> str | None:
        code = self.proc.poll()
        if code is None:
            return None
        tail = " | ".join(list(self.lines)[-3:])
        return f"the hardware twin exited with code {code}" + (f" ({tail})" if tail else "")

    def stop(self, timeout_s: float = 5.0) -> None:
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout_s)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait()


def check_policy_fits_fleet(runtime: PolicyRuntime, fleet: Fleet, scenario: Scenario) -> None:
    """Refuse a policy trained for other robots, another layout or beam count, or another scenario."""
    lidar = runtime.meta["noise"]["lidar"]
    runtime.check_fits(fleet.names, ObservationLayout(runtime.layout.name, int(lidar["beams"])))
    trained = runtime.meta.get("scenario", {}).get("name")
    if trained is not None and trained != scenario.name:
        raise PolicyMismatch(
            runtime.name, [f"it was trained in scenario {trained!r}, the fleet drives in {scenario.name!r}"]
        )


def deploy_policy(
    runtime: PolicyRuntime,
    fleet: Fleet,
    fleet_source: str,
    request: DeployRequest,
    confirm_reset: Callable[[int], None] | None = None,
    twin_extra_args: list[str] | None = None,
) -> tuple[list[EpisodeResult], str]:
    """Run a deployment session; returns the episodes and the reality profile name ('robots' on hardware)."""
    scenario = load_scenario(fleet.scenario, len(fleet.robots))
    # a thread that wants the interpreter waits at most this long: the emitter's tick stays on time
    sys.setswitchinterval(SWITCH_INTERVAL_S)
    check_policy_fits_fleet(runtime, fleet, scenario)
    settings = fleet.network_settings(fleet_source)
    twin: TwinProcess | None = None
    profile = "robots"
    scale = 1.0
    if fleet.target == "twin":
        profile = request.profile or fleet.twin.profile
        scale = request.time_scale or fleet.twin.time_scale
        twin = TwinProcess(fleet_source, profile, scale, fleet.twin.seed, twin_extra_args)
        profile = Path(profile).stem
    transport = None
    log = None
    runner = None
    try:
        transport = open_transport(fleet.transport, settings)
        clock: Clock = ScaledClock(scale) if scale != 1.0 else WallClock()
        session = session_metadata(
            "real",
            scenario.name,
            [r.namespace for r in fleet.robots],
            float(runtime.meta.get("control_period_s", 0.1)),
            runtime.meta,
            profile=profile,
            extra={"target": fleet.target, "time_scale": repr(scale), "fleet": fleet_source},
        )
        documents = {
            "params": request.params_text,
            "scenario": dumps(to_mapping(scenario)),
            "fleet": dumps(to_mapping(fleet)),
            "policy": dumps(runtime.meta),
        }
        log = SessionLog(
            request.recording, [r.namespace for r in fleet.robots], session, documents, request.chunk_size_bytes
        )
        if twin is not None:
            twin.wait_ready(TWIN_START_TIMEOUT_S)
        runner = DeployRunner(
            runtime,
            fleet,
            scenario,
            transport,
            clock,
            log,
            fleet_alive=(twin.problem if twin is not None else lambda: None),
            confirm_reset=confirm_reset if fleet.target == "robots" else None,
        )
        runner.wait_for_fleet(fleet.timing.discovery_timeout_s)
        results = runner.run(request.episodes, request.seed, request.progress)
        return results, profile
    finally:
        if runner is not None:
            runner.close()
        if log is not None:
            log.close()
        if transport is not None:
            transport.close()
        if twin is not None:
            twin.stop()
