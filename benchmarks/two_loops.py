"""Two users on one machine: two ``dvc repro`` loops in two clones, side by side, each against its own reality.

    python benchmarks/two_loops.py --out DIR [--profiles lab harsh] [--full]

Copies the checkout's tracked files twice (two clones without history, as two users have), sets each clone's
``deploy.profile`` to one of --profiles, and runs ``dvc repro`` in both at once, each clone on its own source
(PYTHONPATH) and with the bundled twin fleet, whose deployments take a free DDS domain each. By default the loops run
on the tiny budget of :mod:`pipeline.bench.tiny_loop` (every stage, a few thousand training steps: the machinery, not
the policies); --full keeps params.yaml's budget (about an hour side by side on 2 cores).

Printed per loop: its exit code and wall time, the slowest stage, and per deployment round its episodes, aborted
episodes, episodes whose clock was not kept and robot success over every episode. Written to --out: run.json (command,
commit, per-loop figures) and each loop's stage times and deployment metrics. Last line:
``both_finished=<bool> walls_s=<a>,<b> aborted=<a>,<b> clock_not_kept=<a>,<b>``.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import yaml
from collect_results import ROOT, commit_of  # this folder: the script's own

from pipeline.bench.tiny_loop import copy_checkout, tiny_params

ROUNDS = ("nominal", "calibrated")


def prepare(dest: Path, profile: str, full: bool) -> Path:
    """A clone of this checkout at `dest` whose loop deploys against `profile`, committed (dvc wants a git repo)."""
    copy_checkout(ROOT, dest)
    params = yaml.safe_load((dest / "params.yaml").read_text(encoding="utf-8"))
    params = params if full else tiny_params(params)
    params["deploy"]["profile"] = profile
    (dest / "params.yaml").write_text(yaml.safe_dump(params, sort_keys=False), encoding="utf-8")
    env = {**os.environ, "GIT_AUTHOR_NAME": "bench", "GIT_AUTHOR_EMAIL": "bench@localhost"}
    env.update(GIT_COMMITTER_NAME="bench", GIT_COMMITTER_EMAIL="bench@localhost")
    for cmd in (["git", "init", "-q"], ["git", "add", "-A"], ["git", "commit", "-qm", f"loop on {profile}"]):
        subprocess.run(cmd, cwd=dest, env=env, check=True, capture_output=True)
    return dest


def figures(clone: Path) -> dict[str, object]:
    """The loop's stage times and, per deployment round, its episode counts and robot success."""
    out: dict[str, object] = {}
    stages = {}
    for path in sorted((clone / "logs" / "stages").glob("*.json")):
        record = json.loads(path.read_text(encoding="utf-8"))
        stages[record["stage"]] = record["seconds"]
    out["stages_s"] = stages
    for round_ in ROUNDS:
        path = clone / "logs" / "real" / round_ / "metrics.json"
        if path.is_file():
            m = json.loads(path.read_text(encoding="utf-8"))
            out[round_] = {
                k: m.get(f"real/{k}")
                for k in ("episodes", "aborted_episodes", "clock_not_kept_episodes", "robot_success")
            }
    return out


def _round(loop: dict[str, object], round_: str) -> dict[str, float]:
    found = loop.get(round_)
    return found if isinstance(found, dict) else {}


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--profiles", nargs=2, default=["lab", "harsh"], metavar="PROFILE")
    parser.add_argument("--full", action="store_true", help="params.yaml's budget instead of the tiny one")
    args = parser.parse_args()
    commit = commit_of(ROOT)
    args.out.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(prefix="two-loops-") as tmp:
        clones = [prepare(Path(tmp) / f"user{k + 1}", p, args.full) for k, p in enumerate(args.profiles)]
        procs, logs, starts = [], [], []
        for clone in clones:
            env = {
                **os.environ,
                "PYTHONPATH": str(clone),
                "PATH": f"{Path(sys.executable).parent}:{os.environ['PATH']}",
            }
            log = (clone / "repro.log").open("w")
            logs.append(log)
            starts.append(time.perf_counter())
            procs.append(
                subprocess.Popen(
                    [sys.executable, "-m", "dvc", "repro"], cwd=clone, env=env, stdout=log, stderr=subprocess.STDOUT
                )
            )
            print(f"two_loops: {clone.name} started", flush=True)
        walls: list[float] = [0.0, 0.0]
        pending = set(range(len(procs)))
        while pending:
            for k in sorted(pending):
                if procs[k].poll() is not None:
                    walls[k] = time.perf_counter() - starts[k]
                    pending.discard(k)
                    print(f"two_loops: {clones[k].name} exit {procs[k].returncode} after {walls[k]:.0f} s", flush=True)
            time.sleep(1.0)
        for log in logs:
            log.close()
        result = []
        for k, (clone, profile) in enumerate(zip(clones, args.profiles, strict=True)):
            found = figures(clone)
            folder = args.out / clone.name
            folder.mkdir(parents=True, exist_ok=True)
            if procs[k].returncode != 0:
                shutil.copy2(clone / "repro.log", folder / "repro.log")
            for path in (clone / "logs" / "stages").glob("*.json"):
                (folder / "stages").mkdir(exist_ok=True)
                shutil.copy2(path, folder / "stages" / path.name)
            for round_ in ROUNDS:
                metrics = clone / "logs" / "real" / round_ / "metrics.json"
                if metrics.is_file():
                    shutil.copy2(metrics, folder / f"real_{round_}_metrics.json")
            stages = found["stages_s"]
            slowest = max(stages, key=stages.get) if isinstance(stages, dict) and stages else "-"  # type: ignore[arg-type]
            print(
                f"two_loops: {clone.name} on {profile}: exit {procs[k].returncode}, {walls[k]:.0f} s, "
                f"slowest stage {slowest}"
            )
            for round_ in ROUNDS:
                r = found.get(round_)
                if isinstance(r, dict):
                    print(
                        f"  deploy@{round_}: {r['episodes']:.0f} episodes, {r['aborted_episodes']:.0f} aborted, "
                        f"clock not kept in {r['clock_not_kept_episodes']:.0f}, robot success {r['robot_success']:.3f}"
                    )
            result.append({"clone": clone.name, "profile": profile, "exit": procs[k].returncode,
                           "wall_s": round(walls[k], 1), **found})  # fmt: skip
    run = {
        "command": "python " + " ".join([Path(sys.argv[0]).as_posix(), *sys.argv[1:]]),
        "commit": commit,
        "budget": "params.yaml" if args.full else "pipeline.bench.tiny_loop.TINY_LOOP",
        "loops": result,
    }
    (args.out / "run.json").write_text(json.dumps(run, indent=2) + "\n", encoding="utf-8")

    def each(key: str) -> str:
        return ",".join(f"{sum(_round(r, x).get(key) or 0 for x in ROUNDS):.0f}" for r in result)

    both = all(r["exit"] == 0 for r in result)
    print(
        f"both_finished={both} walls_s={','.join(str(round(w)) for w in walls)} "
        f"aborted={each('aborted_episodes')} clock_not_kept={each('clock_not_kept_episodes')}"
    )
    return 0 if both else 1


if __name__ == "__main__":
    sys.exit(main())
