"""dvc stage `calibrate`: estimate the fleet's lidar, actuation, odometry and network from a deployment
recording, and write the calibration file the calibrated round trains with, plus a fit report."""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from pipeline.analysis.errors import ReplayError
from pipeline.analysis.replay import open_loop_divergence, residual_lines
from pipeline.calibration import Calibration, calibrate, calibration_settings, write_calibration
from pipeline.calibration.fit_report import spectrum_lines
from pipeline.core.scenario import load_scenario
from pipeline.params import Params, calibrated_world, load_params
from pipeline.stage import STAGE_TIMES, run_stage, stage_arguments


def main(argv: Sequence[str] | None = None) -> int:
    args = stage_arguments(__doc__ or "", argv, rounds=False)
    params = load_params(args.params)
    cfg = params.calibrate
    settings = calibration_settings(
        {
            "parts": list(cfg.parts),
            "scenario": params.world.scenario,
            "stationary_min_s": cfg.stationary_min_s,
            "bootstrap": cfg.bootstrap,
            "seed": cfg.seed,
        },
        source=f"{args.params} (calibrate)",
    )
    recording = Path(params.deploy.out_dir) / cfg.round / "session.mcap"
    calibration = calibrate(
        [recording], settings, progress=lambda stage: print(f"calibrate: {stage}", file=sys.stderr, flush=True)
    )
    path = write_calibration(calibration, cfg.out_dir)
    write_residuals(params, calibration, recording, path)
    for key, reason in calibration.unidentified().items():
        print(f"calibrate: {key} unidentifiable: {reason}")
    print(f"calibrate: {path} from {recording}")
    return 0


def write_residuals(params: Params, calibration: Calibration, recording: Path, path: Path) -> None:
    """Append to the fit report what the calibrated simulator still leaves unexplained: the open-loop replay
    error of the recording's commands (nominal vs calibrated point estimates) and the scan residual."""
    scenario = load_scenario(params.world.scenario)
    horizon, episodes = params.replay.horizon_s, params.replay.max_episodes
    lines = ["", "## What the calibrated simulator still leaves", ""]
    report = path.parent / "calibration.md"
    try:
        nominal = open_loop_divergence(recording, scenario, params.world, horizon, episodes)
        calibrated = open_loop_divergence(recording, scenario, calibrated_world(params.world, path), horizon, episodes)
    except ReplayError as exc:
        with report.open("a", encoding="utf-8") as f:
            f.write("\n".join([*lines, f"No open-loop replay: {exc}"]) + "\n")
        print(f"calibrate: no open-loop replay: {exc}")
        return
    lines += [
        f"Open-loop replay of the recording's commands from the recorded start poses ({calibrated.episodes} "
        "episode(s); position error against the recorded ground truth):",
        "",
        *residual_lines(nominal, calibrated),
        "",
    ]
    t = min(float(calibrated.times_s[-1]), horizon)
    lines.append(
        f"At {t:g} s the calibrated simulator is {calibrated.at(t):.3f} m off: "
        + (
            "not near zero. The reality has physics the simulator does not contain (wheel slip, motor lag and "
            "deadband, an acceleration limit); domain randomization in training is what covers the rest."
            if calibrated.at(t) >= 0.02
            else "under 2 cm, so the simulator explains this recording's motion closely."
        )
    )
    fit = calibration.lidar
    if fit is not None and len(fit.residuals_m) and fit.noise_sigma_m.ok and fit.noise_sigma_m.value is not None:
        r = fit.residuals_m
        spread = 1.4826 * float(np.median(np.abs(r - np.median(r))))
        lines.append(
            f"Scans while standing still: residual to the calibrated map {spread:.4f} m (robust spread) against a "
            f"sensor noise of "
            f"{fit.noise_sigma_m.value:.4f} m (+{(fit.noise_per_m.value or 0.0):.4f} per m of range)."
        )
    spectrum = calibration.lidar.residual_spectrum if calibration.lidar is not None else None
    if spectrum is not None:
        bands = spectrum.bands()
        excess = [(lo, hi, p / n) for lo, hi, p, n in bands if n > 0]
        worst = max(excess, key=lambda b: b[2]) if excess else None
        lines += ["", *spectrum_lines(calibration), ""]
        if worst is not None:
            lines.append(
                f"The residual carries {worst[2]:.1f} times the noise's power at {worst[0]}-{worst[1]} cycles per "
                "revolution: "
                + (
                    "structure the calibrated map and lidar model do not explain, not noise."
                    if worst[2] >= 2.0
                    else "within a factor 2 of the noise at every frequency, so the calibrated map and lidar explain "
                    "the stationary scans."
                )
            )
    with report.open("a", encoding="utf-8") as f:
        f.write("\n".join(lines) + "\n")
    errors = f"nominal {nominal.at(t):.3f} m, calibrated {calibrated.at(t):.3f} m"
    print(f"calibrate: open-loop replay error at {t:g} s: {errors}")


if __name__ == "__main__":
    sys.exit(run_stage("calibrate", main, STAGE_TIMES))
