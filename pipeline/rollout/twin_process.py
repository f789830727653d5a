"""The hardware twin as a child process of a deployment: started, watched (its ready line, its pace reports, its
output kept for error messages), asked for another time scale over its lifeline, stopped; and its record of how it
kept its clock per episode, read back into the episodes."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import threading
import time
from collections import deque
from dataclasses import replace
from pathlib import Path
from typing import Any

from pipeline.core.episode import EpisodeResult
from pipeline.rollout.errors import FleetNotReady
from pipeline.rollout.pace import Pace

TWIN_START_TIMEOUT_S = 60.0


class TwinProcess:
    """The hardware twin as a child process; its output is kept for error messages."""

    def __init__(
        self,
        fleet_source: str,
        profile: str,
        time_scale: float,
        seed: int,
        extra: list[str] | None = None,
        domain_id: int | None = None,
    ):
        cmd = [sys.executable, "-m", "pipeline.twin", "--fleet", fleet_source, "--profile", profile]
        cmd += ["--time-scale", repr(time_scale), "--seed", str(seed), "--exit-with-parent", *(extra or [])]
        if domain_id is not None:  # the deployment's domain where it is not the fleet file's (mrl deploy --domain-id)
            cmd += ["--domain-id", str(domain_id)]
        # its own session keeps a terminal's Ctrl-C for the runner, which stops the robots first; the
        # lifeline (its stdin, whose other end only this process holds) stops it when this process dies
        self.proc = subprocess.Popen(
            cmd,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            text=True,
            start_new_session=True,
        )
        self.lines: deque[str] = deque(maxlen=50)
        self.paces: list[Pace] = []
        """Its pace reports (``--pace``), as they arrive."""
        self.ready = threading.Event()
        self.participant = ""
        """The twin's participant on the domain (from its ready line): the only writers the runner will hear."""
        threading.Thread(target=self._pump, args=(self.proc.stdout,), daemon=True).start()
        threading.Thread(target=self._pump, args=(self.proc.stderr,), daemon=True).start()

    def _pump(self, stream: object) -> None:
        for line in stream:  # type: ignore[attr-defined]
            if line.startswith("twin: pace "):
                try:
                    self.paces.append(Pace(**json.loads(line.removeprefix("twin: pace "))))
                    continue
                except (ValueError, TypeError):
                    pass  # kept as any other line
            self.lines.append(line.rstrip())
            if line.startswith("twin: ready"):
                found = re.search(r"participant (\S+)", line)
                self.participant = found.group(1) if found else ""
                self.ready.set()

    def ask_scale(self, scale: float) -> None:
        """Ask the twin (started with ``--pace``) to run at `scale` from its next episode on (at once before the
        first), over its lifeline."""
        if self.proc.stdin is not None and not self.proc.stdin.closed:
            try:
                self.proc.stdin.write(f"time-scale {scale!r}\n")
                self.proc.stdin.flush()
            except (BrokenPipeError, OSError):
                pass  # a twin that is gone is the runner's fault to report

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
        tail = " | ".join(line.strip() for line in list(self.lines)[-20:])
        return f"the hardware twin exited with code {code}" + (f" ({tail})" if tail else "")

    def stop(self, timeout_s: float = 5.0) -> None:
        if self.proc.stdin is not None and not self.proc.stdin.closed:
            self.proc.stdin.close()
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(timeout_s)
            except subprocess.TimeoutExpired:
                os.killpg(self.proc.pid, signal.SIGKILL)
                self.proc.wait()


def stop_twin(twin: TwinProcess) -> None:
    if twin.proc.poll() is None:
        twin.stop()


def read_timing(timing_file: Path) -> dict[int, dict[str, Any]]:
    """Per episode, how the twin kept its clock (its ``--timing-record``, written as it stopped); empty where a twin
    that died wrote none (its episodes' failure is already the runtime fault's)."""
    try:
        return {int(r["episode"]): r for r in json.loads(timing_file.read_text(encoding="utf-8"))}
    except (OSError, ValueError, KeyError, TypeError):
        return {}


def with_timing(results: list[EpisodeResult], records: dict[int, dict[str, Any]]) -> list[EpisodeResult]:
    """The episodes with how the twin kept its clock in each (`read_timing`)."""
    out = []
    for result in results:
        record = records.get(result.episode)
        if record is None:
            out.append(result)
            continue
        out.append(
            replace(
                result,
                time_scale_asked=float(record["time_scale_asked"]),
                time_scale_realized=float(record["time_scale_realized"]),
                clock_kept=result.clock_kept and bool(record["kept"]),
            )
        )
    return out
