"""Reality profiles: the twin's lidar, actuation, odometry and network, in the keys calibration estimates.

The keys (units in the names) are::

    lidar:     {beams, rate_hz, noise_sigma_m, dropout_prob, bias_m, mount_yaw_rad}
    actuation: {delay_s, time_constant_s, linear_gain, angular_gain}
    odometry:  {rate_hz, drift_per_m}
    network:   {loss_prob, jitter_s}
"""

from __future__ import annotations

from dataclasses import dataclass
from importlib import resources
from pathlib import Path

from pipeline.errors import ConfigError, ConfigProblem
from pipeline.mappings import from_mapping, read_yaml, setting


@dataclass(frozen=True)
class LidarProfile:
    beams: int = setting(ge=4, le=4096)
    rate_hz: float = setting(gt=0.0, le=100.0)
    noise_sigma_m: float = setting(ge=0.0, le=1.0)
    dropout_prob: float = setting(ge=0.0, lt=1.0)
    bias_m: float = setting(ge=-0.5, le=0.5)
    mount_yaw_rad: float = setting(ge=-3.15, le=3.15)


@dataclass(frozen=True)
class ActuationProfile:
    delay_s: float = setting(ge=0.0, le=1.0)
    time_constant_s: float = setting(gt=0.0, le=2.0)
    linear_gain: float = setting(gt=0.0, le=5.0)
    angular_gain: float = setting(gt=0.0, le=5.0)


@dataclass(frozen=True)
class OdometryProfile:
    rate_hz: float = setting(gt=0.0, le=1000.0)
    drift_per_m: float = setting(ge=0.0, le=1.0)


@dataclass(frozen=True)
class NetworkProfile:
    loss_prob: float = setting(ge=0.0, lt=1.0)
    jitter_s: float = setting(ge=0.0, le=1.0)


@dataclass(frozen=True)
class RealityProfile:
    """What the twin's robots are really like; `name` is the file's stem."""

    lidar: LidarProfile = setting()
    actuation: ActuationProfile = setting()
    odometry: OdometryProfile = setting()
    network: NetworkProfile = setting()


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
