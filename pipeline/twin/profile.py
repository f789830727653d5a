"""Reality profile files: the bundled ones (``pipeline/twin/profiles/*.yaml``: lab, mild, ...) or a YAML path.

The keys, their units and bounds are the schema of :mod:`pipeline.core.reality`, the one definition the twin,
calibration and the simulator share.
"""

from __future__ import annotations

from importlib import resources
from pathlib import Path

from pipeline.core.reality import (
    NOMINAL_WHEEL_RADIUS_M,
    NOMINAL_WHEEL_SEPARATION_M,
    ActuationProfile,
    BaseProfile,
    ClockProfile,
    LidarProfile,
    MapProfile,
    NetworkProfile,
    OdometryProfile,
    RealityProfile,
)
from pipeline.core.scenario import Scenario
from pipeline.errors import ConfigError, ConfigProblem
from pipeline.mappings import from_mapping, read_yaml

__all__ = [
    "NOMINAL_WHEEL_RADIUS_M",
    "NOMINAL_WHEEL_SEPARATION_M",
    "ActuationProfile",
    "BaseProfile",
    "ClockProfile",
    "LidarProfile",
    "MapProfile",
    "NetworkProfile",
    "OdometryProfile",
    "RealityProfile",
    "bundled_profiles",
    "load_profile",
    "load_profile_for",
    "profile_path",
]
"""The schema lives in :mod:`pipeline.core.reality`; this module finds and loads the profile files."""


def bundled_profiles() -> tuple[str, ...]:
    folder = resources.files("pipeline.twin") / "profiles"
    return tuple(sorted(p.name[: -len(".yaml")] for p in folder.iterdir() if p.name.endswith(".yaml")))


def profile_path(spec: str | Path) -> Path:
    text = str(spec)
    if text in bundled_profiles():
        return Path(str(resources.files("pipeline.twin") / "profiles" / f"{text}.yaml"))
    path = Path(text)
    if not path.suffix and not path.exists():
        raise ConfigError(
            "<profile>",
            [
                ConfigProblem(
                    "profile", text, "a bundled profile (" + ", ".join(bundled_profiles()) + ") or a YAML path"
                )
            ],
        )
    return path


def load_profile(spec: str | Path) -> tuple[str, RealityProfile]:
    """(name, profile) from a bundled name or a YAML path; ConfigError names the file and key."""
    path = profile_path(spec)
    return path.stem, from_mapping(RealityProfile, read_yaml(path), str(path))


def load_profile_for(spec: str | Path, scenario: Scenario) -> tuple[str, RealityProfile]:
    """`load_profile`, then the checks that need the room (one box offset per box at most)."""
    name, profile = load_profile(spec)
    problems = profile.problems_in(len(scenario.obstacles))
    if problems:
        raise ConfigError(str(profile_path(spec)), [ConfigProblem(*p) for p in problems])
    return name, profile
