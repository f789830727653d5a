"""The calibration file (``calibration.yaml``) that training reads, and the fit report next to it.

Layout of ``calibration.yaml``:

- ``profile``: the identified values in the reality profile's keys (lidar, actuation, odometry, network, base,
  clock, map);
- ``uncertainty``: every estimated key with its status, and either its value, standard error, 95 %
  interval, unit, method and sample count, or the reason it is unidentifiable;
- ``world``: simulator settings (keys of ``pipeline.params.WorldConfig``) that training applies on
  top of params.yaml's ``world`` (:func:`pipeline.params.calibrated_world`); unidentified values are
  left out, so training keeps their nominal values;
- ``unidentified``: the keys left out and why;
- ``effective``: values of the simulator's model that stand for several of the robot's properties together (the
  drive chain's delay, lag and response time), each with the profile keys it stands for and the model it belongs to;
- ``ambiguous``: where two drive models explain the recording alike (a gain or a speed limit at one commanded speed;
  a delay or a lag), both readings, the one kept and what recording would tell them apart;
- ``trade_offs``: keys whose estimates trade off (the lidar's noise at zero range and its growth, from a short still
  span), their correlation and the combination the data determine;
- ``speed_limits``: per command channel (linear, angular), whether the base saturated and at what speed
  (a top speed, not a gain: the gains are fitted below it), with the largest speeds commanded and achieved;
- ``source``: the recordings (path and session metadata) and the calibration settings.
"""

from __future__ import annotations

import math
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from pipeline.calibration.calibrate import Calibration
from pipeline.calibration.errors import CalibrationError
from pipeline.calibration.keys import split_key, within_physical_ranges
from pipeline.errors import ConfigError
from pipeline.mappings import to_mapping
from pipeline.params import CALIBRATION_FILE, CALIBRATION_FORMAT, world_config

FORMAT = CALIBRATION_FORMAT
REPORT_FILE = "calibration.md"


def calibration_mapping(calibration: Calibration) -> dict[str, Any]:
    """The content of ``calibration.yaml`` as plain mappings (see the module's description). An estimate outside its
    physical range is written as unidentified with its raw figure, never as a setting (the others still are)."""
    calibration = replace(calibration, values=within_physical_ranges(calibration.values))
    uncertainty: dict[str, dict[str, Any]] = {}
    for key, est in calibration.values.items():
        group, name, indices = split_key(key)
        uncertainty.setdefault(group, {})[name + "".join(f"[{i}]" for i in indices)] = est.as_mapping()
    world = calibration.world_overrides()
    try:
        world_config(world, source="<calibrated world>")
    except ConfigError as exc:
        raise CalibrationError("<calibrated world>", f"the estimates are not valid simulator settings: {exc}") from exc
    mapping: dict[str, Any] = as_plain(
        {
            "format": FORMAT,
            "scenario": calibration.scenario,
            "profile": calibration.profile(),
            "uncertainty": uncertainty,
            "world": world,
            "unidentified": calibration.unidentified(),
            "effective": {name: value.as_mapping() for name, value in calibration.effective.items()},
            "ambiguous": [a.as_mapping() for a in (calibration.actuation.ambiguities if calibration.actuation else ())],
            "trade_offs": _trade_offs(calibration),
            "gains": {a.channel: a.as_mapping() for a in calibration.gain_agreement()},
            "speed_limits": {
                limit.channel: limit.as_mapping()
                for limit in (calibration.actuation.speed_limits if calibration.actuation else ())
                if limit is not None
            },
            "source": {
                "recordings": [
                    {
                        "path": s.path,
                        "kind": s.kind,
                        "robots": list(s.robots),
                        "sha256": s.sha256,
                        "episodes": s.episodes,
                        "salvaged": s.salvage,
                        "session": s.session,
                    }
                    for s in calibration.sources
                ],
                "settings": to_mapping(calibration.settings),
                "poses": calibration.pose_source.to_mapping(),
            },
        }
    )
    return mapping


def _trade_offs(calibration: Calibration) -> list[dict[str, Any]]:
    """Keys whose estimates trade off, their correlation and the combination the data determine."""
    lidar = calibration.lidar
    if lidar is None or lidar.noise_at_range is None or not math.isfinite(lidar.noise_correlation):
        return []
    at_m, noise = lidar.noise_at_range
    return [
        {
            "keys": ["lidar.noise_sigma_m", "lidar.noise_per_m"],
            "correlation": round(lidar.noise_correlation, 3),
            "determined": {
                "what": f"the noise (1 sigma) at {at_m:.3g} m, the median range seen: noise_sigma_m + {at_m:.3g} "
                "noise_per_m",
                **noise.as_mapping(),
            },
        }
    ]


def _header(calibration: Calibration) -> str:
    lines = [
        f"# Simulator calibration from {len(calibration.sources)} recording(s) of scenario {calibration.scenario!r}.",
        "# profile: estimates in the reality-profile keys; uncertainty: standard errors and 95 % intervals;",
        "# world: overrides of params.yaml's world section for training (the calibrated round).",
    ]
    poses = calibration.pose_source.sentence()
    if poses:
        lines.append(f"# Poses: {poses}.")
    for limit in calibration.speed_limits():
        lines.append(f"# Saturation: {limit.sentence()}.")
    for ambiguity in calibration.actuation.ambiguities if calibration.actuation else ():
        lines.append(f"# Ambiguous: {ambiguity.sentence()}.")
    for name, value in calibration.effective.items():
        if value.estimate.ok and value.estimate.value is not None:
            lines.append(
                f"# Effective: {name} {value.estimate.value:.3g} {value.estimate.unit} stands for "
                f"{' + '.join(value.stands_for)} together (the simulator's model)."
            )
    missing = calibration.unidentified()
    if missing:
        lines.append("# Not identified (training keeps the nominal value):")
        lines += [f"#   {key}: {reason}" for key, reason in missing.items()]
    return "\n".join(lines) + "\n"


def write_calibration(calibration: Calibration, out_dir: str | Path, report: bool = True) -> Path:
    """Write ``calibration.yaml`` (with `report` also ``calibration.md`` and its plots) into `out_dir`; its path."""
    out = Path(out_dir)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise CalibrationError(str(out), f"cannot create the output folder: {exc.strerror}") from exc
    path = out / CALIBRATION_FILE
    text = _header(calibration) + yaml.safe_dump(calibration_mapping(calibration), sort_keys=False, width=120)
    try:
        path.write_text(text, encoding="utf-8")
    except OSError as exc:
        raise CalibrationError(str(path), f"cannot write: {exc.strerror}") from exc
    if report:
        from pipeline.calibration.fit_report import write_report

        write_report(calibration, out)
    return path


def as_plain(value: Any) -> Any:
    """Numbers and containers as plain Python values for YAML."""
    if isinstance(value, dict):
        return {str(k): as_plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [as_plain(v) for v in value]
    if isinstance(value, (np.floating, float)):
        return float(value)
    if isinstance(value, (np.integer, int)) and not isinstance(value, bool):
        return int(value)
    return value
