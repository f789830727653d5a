"""The loop on a reality the simulator does not contain: nominal vs calibrated, sim vs twin, per reality.

For each --profiles entry (a bundled profile such as ``lab``, or ``drawn:SEED`` for a profile drawn
from `pipeline.twin.draw.PROFILE_RANGES`) it runs the dvc stages with a params file of its own
(params.yaml with the outputs under --out/<profile>/ and the deployment's profile, episodes and time
scale set): the nominal policy (--nominal, an exported policy trained by the nominal round; it is
not retrained) is evaluated in sim and deployed on the twin, the recording is calibrated, the
calibrated round is trained (with its domain randomization), exported, evaluated and deployed.
Printed per profile and round: robot-level success on the twin and in sim with 95 % intervals, and
the gap (sim - twin) with its 95 % interval (Newcombe), twice: in sim at the round world's values
(for the calibrated round, the estimates: the simulator's prediction of this reality; the headline
gap) and under the round's training randomization (`eval_sim.randomized`, not recorded); then
every calibrated key against the profile's truth with its relative error.

Every episode counts: an aborted episode fails the robots that had not arrived (the completed-only rate
is printed beside, named so), and the share of aborted episodes is printed per round.
Targets (issue figures): aborted episodes <= 2 %, twin robot success >= 0.80 nominal and >= 0.90 after
calibration, gap <= 3 points, calibrated never worse than nominal. Last line per profile:
``profile=<name> nominal_real=<p> calibrated_real=<p> gap_calibrated=<points> aborted_nominal=<%>
aborted_calibrated=<%>``.
"""

from __future__ import annotations

import argparse
import shutil
import subprocess
import sys
from pathlib import Path
from typing import Any

import yaml
from calibration_coverage import truth_of

from pipeline.core.stats import newcombe_interval
from pipeline.params import read_calibration_file
from pipeline.record.results import read_session_metrics
from pipeline.twin.draw import draw_profile_mapping
from pipeline.twin.profile import profile_path

ROBOTS = 3
"""Robots of the fleet (the obstacles room's three SPARKs): robot-level trials are episodes x robots."""

ROOT = Path(__file__).resolve().parents[1]


def stage(name: str, params: Path, round_name: str | None = None) -> None:
    cmd = [sys.executable, str(ROOT / "stages" / f"{name}.py"), "--params", str(params)]
    if round_name is not None:
        cmd += ["--round", round_name]
    print(f"sim2real: {' '.join(cmd[1:])}", file=sys.stderr, flush=True)
    subprocess.run(cmd, check=True, cwd=ROOT)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--profiles", nargs="+", default=["lab"])
    parser.add_argument("--nominal", type=Path, default=Path("models/nominal"), help="the nominal round's folder")
    parser.add_argument("--episodes", type=int, default=50)
    parser.add_argument("--time-scale", type=float, default=3.0)
    parser.add_argument("--out", type=Path, default=Path("logs/benchmarks/sim2real"))
    parser.add_argument("--skip-done", action="store_true", help="keep rounds whose metrics exist")
    parser.add_argument(
        "--fleet",
        default=None,
        help="fleet to deploy on (default: params.yaml's); one on a domain of its own lets two runs share a host",
    )
    args = parser.parse_args()
    base = yaml.safe_load((ROOT / "params.yaml").read_text())
    for spec in args.profiles:
        out = (args.out / spec.replace(":", "_")).resolve()
        out.mkdir(parents=True, exist_ok=True)
        if spec.startswith("drawn:"):
            truth = draw_profile_mapping(int(spec.split(":")[1]), 2)
            drawn = out / "profile.yaml"
            drawn.write_text(yaml.safe_dump(truth), encoding="utf-8")
            profile = str(drawn)
        else:
            profile = spec
            truth = yaml.safe_load(profile_path(spec).read_text())
        params = dict(base)
        params["train"] = {**base["train"], "out_dir": str(out / "models")}
        params["export"] = {**base["export"], "out_dir": str(out / "models")}
        params["eval_sim"] = {**base["eval_sim"], "out_dir": str(out / "sim")}
        params["deploy"] = {
            **base["deploy"],
            "out_dir": str(out / "real"),
            "profile": profile,
            "episodes": args.episodes,
            "time_scale": args.time_scale,
            **({"fleet": args.fleet} if args.fleet else {}),
        }
        params["calibrate"] = {**base["calibrate"], "out_dir": str(out / "calibration"), "round": "nominal"}
        params["replay"] = {**base["replay"], "out_dir": str(out / "replay")}
        params_path = out / "params.yaml"
        params_path.write_text(yaml.safe_dump(params, sort_keys=False), encoding="utf-8")
        # the same rounds in sim under their training randomization (a second, unrecorded evaluation)
        randomized = {**params, "eval_sim": {**params["eval_sim"], "out_dir": str(out / "sim_randomized")}}
        randomized["eval_sim"].update(randomized=True, record=False)
        randomized_path = out / "params_randomized.yaml"
        randomized_path.write_text(yaml.safe_dump(randomized, sort_keys=False), encoding="utf-8")
        nominal_dir = out / "models" / "nominal"
        if not nominal_dir.exists():
            shutil.copytree(args.nominal, nominal_dir)
        for round_name in ("nominal", "calibrated"):
            if round_name == "calibrated":
                if not (args.skip_done and (out / "calibration" / "calibration.yaml").exists()):
                    stage("calibrate", params_path)
                if not (args.skip_done and (out / "models" / "calibrated" / "policy" / "policy.json").exists()):
                    stage("train", params_path, round_name)
                    stage("export", params_path, round_name)
            if not (args.skip_done and (out / "sim" / round_name / "metrics.json").exists()):
                stage("eval_sim", params_path, round_name)
            if not (args.skip_done and (out / "sim_randomized" / round_name / "metrics.json").exists()):
                stage("eval_sim", randomized_path, round_name)
            if not (args.skip_done and (out / "real" / round_name / "metrics.json").exists()):
                stage("deploy", params_path, round_name)
        report(spec, out, truth)
    return 0


def report(spec: str, out: Path, truth: dict[str, Any]) -> None:
    print(f"\n== {spec} ==")
    figures = {}
    figures_aborted: dict[str, float] = {}
    for round_name in ("nominal", "calibrated"):
        real = read_session_metrics(out / "real" / round_name / "metrics.json", "real")
        pr = real.robot_success.value
        # every episode counts: an aborted one fails the robots that had not arrived
        n_real = real.episodes * ROBOTS
        aborted = real.aborted_episodes
        stale = ", ".join(f"robot_{i + 1} {v:.1f} s" for i, v in enumerate(real.stale_s_each))
        print(
            f"{round_name:10s} twin {pr:.3f} [{real.robot_success.ci_low:.3f}, "
            f"{real.robot_success.ci_high:.3f}] over all {real.episodes} episodes, "
            f"aborted {aborted} ({100 * aborted / max(real.episodes, 1):.1f} %), completed only "
            f"{real.robot_success_completed.value:.3f}; stale {stale}"
        )
        figures_aborted[round_name] = aborted / max(real.episodes, 1)
        for folder, label in (("sim", "at the world values"), ("sim_randomized", "under its randomization")):
            sim = read_session_metrics(out / folder / round_name / "metrics.json", "eval")
            ps = sim.robot_success.value
            n_sim = sim.episodes * ROBOTS
            lo, hi = newcombe_interval(round(ps * n_sim), n_sim, round(pr * n_real), n_real)
            gap = ps - pr
            figures.setdefault(round_name, (pr, gap))  # the headline gap: the simulator at its values
            sim_ci = f"[{sim.robot_success.ci_low:.3f}, {sim.robot_success.ci_high:.3f}]"
            print(
                f"{'':10s} sim {ps:.3f} {sim_ci} {label:24s}"
                f"  gap {100 * gap:+.1f} points [{100 * lo:+.1f}, {100 * hi:+.1f}]"
            )
    cal = read_calibration_file(out / "calibration" / "calibration.yaml")
    print(f"{'key':30s} {'estimate':>10s} {'truth':>10s} {'rel err':>8s} covered")
    for key, est in cal.keys.items():
        t = truth_of(truth, key)
        if t is None:
            continue
        if not est.ok or est.value is None:
            print(f"{key:30s} {'-':>10s} {t:10.4g}  unidentifiable: {est.reason}")
            continue
        v, (lo, hi) = est.value, est.interval_95 or (float("nan"), float("nan"))
        rel = abs(v - t) / abs(t) if t else float("nan")
        covered = "-" if est.interval_95 is None else "yes" if lo <= t <= hi else "no"  # exact: no interval
        print(f"{key:30s} {v:10.4g} {t:10.4g} {rel:8.3f} {covered}")
    nominal, calibrated = figures["nominal"], figures["calibrated"]
    print(
        f"profile={spec} nominal_real={nominal[0]:.3f} calibrated_real={calibrated[0]:.3f} "
        f"gap_calibrated={100 * calibrated[1]:+.1f} aborted_nominal={100 * figures_aborted['nominal']:.1f}% "
        f"aborted_calibrated={100 * figures_aborted['calibrated']:.1f}%"
    )


if __name__ == "__main__":
    sys.exit(main())
