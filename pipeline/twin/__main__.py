"""``python -m pipeline.twin``: run the hardware twin until SIGINT or SIGTERM.

Example: ``python -m pipeline.twin --fleet twin --profile harsh --time-scale 4``. It prints one
line ``twin: ready ...`` when its topics are up, and exits 0 after a clean shutdown, 2 on bad
input (fleet, profile or scenario files).

With ``--exit-with-parent`` (the deploy runner starts it so) the twin also stops when its standard
input closes: the runner holds the other end of that pipe, so a runner that dies in any way, even
by SIGKILL, takes its twin with it instead of leaving robots publishing on the domain.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import signal
import sys
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import replace
from pathlib import Path
from types import FrameType
from typing import Any

from pipeline.core.scenario import load_scenario
from pipeline.errors import MrlError
from pipeline.ros.clock import Clock, ScaledClock, WallClock
from pipeline.ros.domains import NoFreeDomainError, lease_free_domain
from pipeline.ros.fleet import load_fleet
from pipeline.ros.transport import open_transport
from pipeline.twin.profile import load_profile_for
from pipeline.twin.twin import STALL_JUMP_NS, HardwareTwin, Silence


def parse(argv: Sequence[str] | None, prog: str = "python -m pipeline.twin") -> argparse.Namespace:
    return build_parser(prog).parse_args(argv)


def build_parser(
    prog: str = "python -m pipeline.twin", parser_class: type[argparse.ArgumentParser] = argparse.ArgumentParser
) -> argparse.ArgumentParser:
    """The twin's options; `parser_class` builds the parser (``mrl twin`` gives its verbs' own)."""
    parser = parser_class(prog=prog, description=__doc__.splitlines()[0])
    parser.add_argument("--fleet", default="twin", help="bundled fleet name or fleet YAML (default: twin)")
    parser.add_argument("--profile", default=None, help="bundled profile name or profile YAML (default: the fleet's)")
    parser.add_argument(
        "--time-scale", type=float, default=None, help="twin seconds per wall second (default: the fleet's)"
    )
    parser.add_argument("--seed", type=int, default=None, help="noise seed (default: the fleet's)")
    parser.add_argument(
        "--domain-id", type=int, default=None, help="the DDS domain id (0-232) instead of the fleet file's"
    )
    parser.add_argument(
        "--silence",
        default=None,
        metavar="NS@START[+DURATION]",
        help="fault injection: robot NS stops publishing START seconds after the first reset (for DURATION seconds)",
    )
    parser.add_argument(
        "--stall",
        default=None,
        metavar="SECONDS@START",
        help="fault injection: the host stalls the twin for SECONDS (wall) once, START twin seconds after the first "
        "reset (a busy host)",
    )
    parser.add_argument(
        "--link-record",
        default=None,
        metavar="FILE.npz",
        help="on exit, write what the twin realized: each stamped message's delivery (topic, stamp, time handed on) "
        "and each command as its driver took it (robot, time, v, w)",
    )
    parser.add_argument(
        "--timing-record",
        default=None,
        metavar="FILE.json",
        help="on exit, write how the twin kept its clock in each episode: the time scale asked and realized, the "
        "time jumped over in host stalls, the most it ran behind, whether it kept the scale",
    )
    parser.add_argument(
        "--pace",
        type=float,
        default=None,
        metavar="SECONDS",
        help="every SECONDS (host time) print a line 'twin: pace {...}' with how the twin keeps its clock, and take "
        "'time-scale X' lines on standard input (from the next episode on; a twin started above 1x): the "
        "deployment's --time-scale auto",
    )
    parser.add_argument(
        "--exit-with-parent",
        action="store_true",
        help="stop when standard input closes (the starting process holds the other end of the pipe)",
    )
    return parser


def watch_lifeline(stop: threading.Event, on_line: Callable[[str], None] | None = None) -> None:
    """Set `stop` when standard input reaches end of file: the process holding its other end is gone. Each whole
    line it writes meanwhile goes to `on_line`."""

    fd = sys.stdin.fileno()

    def read() -> None:
        # os.read on the descriptor, not sys.stdin: a daemon thread blocked inside a buffered reader
        # aborts the interpreter at exit (it cannot take the reader's lock)
        pending = b""
        try:
            while chunk := os.read(fd, 4096):
                pending += chunk
                *lines, pending = pending.split(b"\n")
                for line in lines:
                    if on_line is not None:
                        on_line(line.decode("utf-8", "replace").strip())
        except OSError:
            pass
        stop.set()

    threading.Thread(target=read, name="twin-lifeline", daemon=True).start()


def say(line: str) -> None:
    """One line to the starting process; nothing if it is gone (a closed pipe)."""
    try:
        print(line, flush=True)
    except (BrokenPipeError, OSError):
        sys.stdout = open(os.devnull, "w")  # noqa: SIM115 - stays open until exit, so the final flush succeeds


def main(argv: Sequence[str] | None = None, prog: str = "python -m pipeline.twin") -> int:
    """The twin process; `prog` is how it names itself in usage and messages (``mrl twin`` from the command)."""
    args = parse(argv, prog)
    me = "twin" if prog.startswith("python") else prog
    sys.setswitchinterval(0.0002)  # the tick thread gets the interpreter back quickly
    stop = threading.Event()

    def on_signal(signum: int, frame: FrameType | None) -> None:
        stop.set()

    signal.signal(signal.SIGINT, on_signal)
    signal.signal(signal.SIGTERM, on_signal)
    asked: dict[str, Any] = {}  # the twin once it runs; a time scale asked for before it did
    asking = threading.RLock()

    def on_line(line: str) -> None:
        word, _, value = line.partition(" ")
        if word != "time-scale" or args.pace is None:
            say(f"{me}: ignored on standard input: {line!r} (takes 'time-scale X' with --pace)")
            return
        try:
            scale = float(value)
        except ValueError:
            scale = math.nan
        if not 0 < scale <= 20:
            say(f"{me}: ignored on standard input: {line!r} (a time scale in (0, 20])")
            return
        with asking:
            if "twin" not in asked:
                asked["early"] = scale
                return
            try:
                asked["twin"].ask_scale(scale)
            except ValueError as exc:  # a twin at 1x runs on the wall clock: no scale to change
                say(f"{me}: ignored on standard input: {line!r} ({exc})")

    if args.exit_with_parent:
        watch_lifeline(stop, on_line)
    try:
        fleet = load_fleet(args.fleet)
        if args.domain_id is not None:
            fleet = replace(fleet, network=replace(fleet.network, domain_id=args.domain_id))
        elif fleet.network.domain_id is None and fleet.transport != "ros1":  # started by hand: a free domain of its own
            try:
                lease = lease_free_domain()
            except NoFreeDomainError as exc:
                raise MrlError(str(exc)) from exc
            fleet = replace(fleet, network=replace(fleet.network, domain_id=lease.domain_id))
        scenario = load_scenario(fleet.scenario, len(fleet.robots))  # the first robots, as the deployment
        name, profile = load_profile_for(args.profile or fleet.twin.profile, scenario)
        fleet_scale = fleet.twin.time_scale
        if args.time_scale is None and fleet_scale == "auto":
            raise MrlError(
                f"{args.fleet}: twin.time_scale is auto, which a deployment measures and sets; started by hand, the "
                "twin needs --time-scale X"
            )
        scale = float(fleet_scale) if args.time_scale is None else args.time_scale
        if not 0 < scale <= 20:
            raise MrlError(f"--time-scale {scale}: must be in (0, 20]")
        seed = fleet.twin.seed if args.seed is None else args.seed
        for option, value in (("--link-record", args.link_record), ("--timing-record", args.timing_record)):
            if value and not os.path.isdir(os.path.dirname(os.path.abspath(value))):
                raise MrlError(f"{option} {value}: its folder does not exist")
        silence = None
        if args.silence:
            robot, _, when = args.silence.partition("@")
            start, _, duration = when.partition("+")
            try:
                silence = Silence(robot, float(start), float(duration) if duration else None)
            except ValueError:
                raise MrlError(
                    f"--silence {args.silence!r}: expected NAMESPACE@START[+DURATION], e.g. robot_2@3.5+0.6"
                ) from None
            namespaces = [r.namespace for r in fleet.robots]
            if robot not in namespaces:
                raise MrlError(f"--silence {args.silence!r}: no robot {robot!r} in the fleet; its robots: {namespaces}")
        stall = None
        if args.stall:
            seconds, _, start_text = args.stall.partition("@")
            try:
                stall = (float(seconds), float(start_text or 0.0))
            except ValueError:
                raise MrlError(f"--stall {args.stall!r}: expected SECONDS@START, e.g. 2.0@1.5") from None
            if not (stall[0] > 0 and stall[1] >= 0):
                raise MrlError(f"--stall {args.stall!r}: SECONDS above 0, START at least 0")
        if args.pace is not None and not 0 < args.pace <= 60:
            raise MrlError(f"--pace {args.pace}: must be in (0, 60] seconds")
        scaled = scale != 1.0
        clock: Clock = ScaledClock(scale, time.time_ns()) if scaled else WallClock()
        transport = open_transport(fleet.transport, fleet.network_settings(args.fleet, on_this_host=True))
    except MrlError as exc:
        print(f"{me}: {exc}", file=sys.stderr)
        return 2
    try:
        twin = HardwareTwin(fleet, scenario, profile, transport, clock, seed, publish_clock=scaled, silence=silence)
        twin.stall = stall
        if args.pace is not None:
            twin.pace_every_s = args.pace
            twin.on_pace = lambda pace: say("twin: pace " + json.dumps(pace))
            with asking:
                asked["twin"] = twin
                if "early" in asked:
                    on_line(f"time-scale {asked.pop('early')!r}")
        robots = ", ".join(r.namespace for r in fleet.robots)
        identity = transport.identity()
        say(
            f"twin: ready, profile {name}, {len(fleet.robots)} robots ({robots}), time scale {scale}"
            + (f", DDS domain {fleet.network.domain}" if fleet.transport != "ros1" else "")
            + (f", participant {identity}" if identity else "")
        )
        if args.link_record:
            twin.link.deliveries = []
            twin.applied = []
        try:
            twin.run(stop)
        finally:
            twin.close()
            twin.close_timing()
            if args.link_record:
                twin.write_record(args.link_record)
            if args.timing_record:
                text = json.dumps([t.as_mapping() for t in twin.timing], indent=1)
                Path(args.timing_record).write_text(text + "\n", encoding="utf-8")
    finally:
        transport.close()
    jumped = ""
    if twin.jumps:
        total = sum(j[1] for j in twin.jumps) / 1e9
        jumped = (
            f"; the host stalled {len(twin.jumps)} time(s) beyond {STALL_JUMP_NS / 1e9:g} s of twin time and the "
            f"robots stood still through {total:.2f} s of it"
        )
    say(f"twin: stopped after {twin.ticks} ticks ({twin.link.sent} messages sent, {twin.link.lost} lost){jumped}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
