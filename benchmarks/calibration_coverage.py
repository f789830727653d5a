"""Honesty of calibration: how often each key's 95 % interval covers the truth, over random realities.

For each of --profiles reality profiles drawn from `pipeline.twin.draw.PROFILE_RANGES` (seeds
--seed, --seed + 1, ...), the exported policy (--policy) is deployed on the twin for --episodes
episodes at --time-scale (with --drive excitation, the calibration drive over it: held steps of several
sizes between the policy's driving, pipeline/policy/excitation.py), the recording is calibrated, and every
estimated key is compared with the profile's true value. Printed per key: profiles where it was identified,
coverage of the 95 % interval (target >= 0.90), median relative error and median interval half-width.

Some calibrated keys are the simulator's own parameters of an effect the twin produces differently. The drive
chain's (`REPLAYED`: ``effective.drive_delay_s``, ``drive_lag_s``, ``drive_response_s`` and the linear and angular
gains) are scored against what they stand for on that recording: the simulator's drive model fitted, by the same
fit, on the same contact-free stretches and commands, to the body velocities of the reality's own drive replayed
noise-free (benchmarks/drive_replay.py: the profile's driver, motors, deadband, acceleration limit and floor
in the twin's physics, under the commands as the twin's driver took them: the twin records when each took effect,
so the command path's latency on a busy host is the replay's too; the recording's command times where the twin
kept no record). ``network.jitter_s`` is scored against
the jitter the twin's link realized on that run (`REALIZED`): the twin records each stamped message's hand-over
(``--link-record``) and calibration's pair rule reads those deliveries at the sender, free of the recorder's side; a
busy twin realizes less than its profile's jitter (benchmarks/twin_link_jitter.py), and the profile's value is in the
CSV beside it (``profile_truth``). ``actuation.delay_s`` (the delay from a command's time in the recording to its
effect at the wheels: the simulator has no command path of its own, so its delay holds the path's) is scored against
the profile's driver delay plus the command path's mean latency realized on the run (:func:`command_path_s`: the
recorded commands against when the twin's driver took them); the profile's driver delay alone is ``profile_truth``.
``odometry.drift_per_m`` keeps the profile's truth (the random part of the
odometry's errors; the systematic part of wheels unlike the odometry's nominal ones widens its interval). A low
coverage says the simulator's model does not contain the twin's: it is reported, not hidden. --ranges wide
(the default) draws from `pipeline.twin.draw.WIDE_RANGES`, the ranges of real robots; --ranges drawn from the
sim2real benchmark's narrower ones.

--keep DIR keeps each profile and recording (``drawn_<seed>.yaml``, ``drawn_<seed>.mcap``);
--recalibrate DIR deploys nothing and calibrates the recordings a --keep run left there again (to
measure a change of the calibration on the same data); --pool CSV... deploys and calibrates nothing and prints the
summary over several runs' rows (other profiles: more drawn robots), a key scored against different truths in
different runs summarized per truth; with --parts only those parts of calibration run and
their keys are scored (e.g. ``--parts lidar``: seconds per recording).

``clock.offset_s`` is reported unidentifiable on a time-scaled twin (the recorder follows ``/clock``) and is
not counted. Rows go to --out (CSV); progress on stderr. Last line: ``coverage_min=<lowest coverage over the
keys> keys_at_target=<k>/<n> identifiable_within_15pct=<k>/<n> keys_consistent_with_95=<k>/<n>
determined_within_15pct=<k>/<n> pooled_coverage=<share>`` (`summary`: a key's coverage with its Clopper-Pearson
interval and a binomial test against 95 %, as a per-key 90 % target over 20 realities fails exact intervals by
chance; the relative error also over the estimates whose interval is narrower than their value).
"""

from __future__ import annotations

import argparse
import csv
import math
import sys
import tempfile
import time
from contextlib import nullcontext
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from coverage_keys import split_by_truth
from drive_replay import ReplayedDrive, replay_drive, replayed_tracks

from pipeline.calibration import calibrate
from pipeline.calibration.actuation import CommandTimeline, estimate_actuation
from pipeline.calibration.calibrate import DriveRecord, drive_record
from pipeline.calibration.network import pair_rule
from pipeline.calibration.options import PARTS, CalibrationSettings, Part
from pipeline.calibration.recording import SessionData
from pipeline.core.scenario import load_scenario
from pipeline.core.timebase import NS_PER_S
from pipeline.errors import MrlError
from pipeline.policy.excitation import ExcitationDrive
from pipeline.policy.runtime import PolicyRuntime
from pipeline.rollout.deployment import DeployRequest, deploy_policy
from pipeline.ros.fleet import load_fleet
from pipeline.twin.draw import PROFILE_RANGES, WIDE_RANGES, draw_profile_mapping
from pipeline.twin.profile import NOMINAL_WHEEL_RADIUS_M, load_profile, load_profile_for, profile_path

IDENTIFIABLE = (
    "lidar.range_step_m",
    "lidar.rate_wander",
    "lidar.scan_drop_prob",
    "lidar.mixed_pixel_prob",
    "lidar.beam_noise_spread",
    "lidar.noise_sigma_m",
    "lidar.noise_per_m",
    "lidar.noise_at_range",
    "lidar.noise_at_range_driving",
    "lidar.dropout_prob",
    "lidar.bias_m",
    "lidar.mount_yaw_rad",
    "lidar.mount_xy_m[0]",
    "lidar.mount_xy_m[1]",
    "lidar.rate_hz",
    "odometry.rate_hz",
    "base.wheel_radius_left_m",
    "base.wheel_radius_right_m",
    "base.wheel_separation_m",
    "base.deadband_radps",
    "base.max_wheel_accel_radps2",
    "base.motor_time_constant_s",
    "actuation.delay_s",
    "actuation.time_constant_s",
    "clock.drift_ppm",
    "map.wall_offset_m",
    "network.loss_prob",
    "network.burst_len",
)
EFFECTIVE = (
    "actuation.linear_gain",
    "actuation.angular_gain",
    "odometry.drift_per_m",
    "network.jitter_s",
)
REPLAYED = {
    "effective.drive_delay_s": "delay_s",
    "effective.drive_lag_s": "time_constant_s",
    "effective.drive_response_s": "response_s",
    "actuation.linear_gain": "linear_gain",
    "actuation.angular_gain": "angular_gain",
}
"""The keys scored against the drive model's fit to the reality's own drive replayed (key: the drive fit's field)."""
REALIZED = ("network.jitter_s", "actuation.delay_s")
"""The keys scored against what the twin realized on the run (its link's recorded deliveries; the commands as its
driver took them)."""
MATCH_WINDOW_S = 0.5
"""A recorded command is matched to the first command of the same values that the twin's driver took after it and
before the robot's next recorded command (within this long at most): a later one of the same values is the next
command's arrival where this one was lost among held commands. One with none is left out of the path's mean (a
latency longer than the commands' period is not told from a loss)."""
SENSOR_KINDS = ("/ground_truth", "/odom", "/scan")
"""The topics calibration reads the network from."""


def realized_jitter(deliveries: Path) -> float | None:
    """The jitter (s) that the twin's link realized, read by calibration's pair rule (the interquartile range of two
    topics' delay differences for the same stamp, over 2 - sqrt 2; the median over topic pairs sharing stamps) from
    the deliveries it recorded (``python -m pipeline.twin --link-record``). None without two such topics."""
    with np.load(deliveries) as data:
        topics, stamps, handed = data["topic"], data["stamp_ns"], data["handed_ns"]
    by_topic: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for topic in np.unique(topics):
        if not str(topic).endswith(SENSOR_KINDS):
            continue
        sel = topics == topic
        stamp, first = np.unique(stamps[sel], return_index=True)
        by_topic[str(topic)] = (stamp, (handed[sel][first] - stamp).astype(np.float64))
    names = sorted(by_topic)
    pairs: list[float] = []
    for i, a in enumerate(names):
        for b in names[i + 1 :]:
            common, ia, ib = np.intersect1d(by_topic[a][0], by_topic[b][0], return_indices=True)
            if len(common) < 50:
                continue
            pairs.append(pair_rule((by_topic[a][1][ia] - by_topic[b][1][ib]) / 1e9))
    return float(np.median(pairs)) if pairs else None


def applied_commands(deliveries: Path) -> dict[str, CommandTimeline] | None:
    """Per robot, the commands as the twin's driver took them (``python -m pipeline.twin --link-record``); None where
    the record holds none."""
    with np.load(deliveries) as data:
        if "cmd_robot" not in data or not len(data["cmd_robot"]):
            return None
        robot, t, v, w = data["cmd_robot"], data["cmd_ns"], data["cmd_v"], data["cmd_w"]
    return {
        str(name): CommandTimeline(t[robot == name], np.stack([v[robot == name], w[robot == name]], axis=1))
        for name in np.unique(robot)
    }


def command_path_s(session: SessionData, applied: dict[str, CommandTimeline]) -> tuple[float, int] | None:
    """The mean latency (s) of the commands' path as the twin realized it, and the number of commands it is the mean
    of: from each command's time in the recording (what calibration reads the delay from) to when the twin's driver
    took it (`applied`, its record), matched per robot as `MATCH_WINDOW_S` says. The mean, not the median: a single
    delay fitted to responses under a varying latency reads (to first order) its mean. None where no command
    matches."""
    gaps: list[np.ndarray] = []
    window = round(MATCH_WINDOW_S * NS_PER_S)
    for robot in session.robots:
        taken, sent = applied.get(robot.name), robot.commands
        if taken is None or sent is None or not len(sent.t_ns) or not len(taken.t_ns):
            continue
        values = np.stack([sent.v, sent.w], axis=1)
        first = np.searchsorted(taken.t_ns, sent.t_ns, side="left")
        gap = np.full(len(sent.t_ns), -1, dtype=np.int64)
        ends = np.minimum(np.append(sent.t_ns[1:], np.iinfo(np.int64).max), sent.t_ns + window)
        for i, (t, k) in enumerate(zip(sent.t_ns, first, strict=True)):
            while k < len(taken.t_ns) and taken.t_ns[k] < ends[i]:
                if np.array_equal(taken.values[k], values[i]):
                    gap[i] = taken.t_ns[k] - t
                    break
                k += 1
        gaps.append(gap[gap >= 0])
    matched = np.concatenate(gaps) if gaps else np.zeros(0, dtype=np.int64)
    return (float(np.mean(matched)) / NS_PER_S, len(matched)) if len(matched) else None


def drive_replayed(
    recording: Path, profile_file: Path, settings: CalibrationSettings, deliveries: Path | None = None
) -> tuple[DriveRecord, dict[str, ReplayedDrive]]:
    """`recording`'s drive record and the profile's own drive replayed noise-free under the commands as the twin's
    driver took them where `deliveries` records them (when each took effect on the twin's clock: the command path's
    latency as the twin realized it), else the recording's, standing still through the stalls the twin jumped."""
    record = drive_record(recording, settings)
    _, profile = load_profile(profile_file)
    if len(record.sessions) != 1:
        raise SystemExit(f"calibration_coverage: {recording} holds {len(record.sessions)} sessions; one is replayed")
    record_file = deliveries if deliveries is not None and deliveries.is_file() else None
    applied = applied_commands(record_file) if record_file is not None else None
    frozen = jumps(record_file) if record_file is not None else []
    return record, replay_drive(record.sessions[0], profile, applied, frozen)


def drive_truths(
    recording: Path,
    profile_file: Path,
    settings: CalibrationSettings,
    deliveries: Path | None = None,
    replayed: tuple[DriveRecord, dict[str, ReplayedDrive]] | None = None,
) -> dict[str, float | None]:
    """What each of `REPLAYED` stands for on `recording`: the simulator's drive model fitted to the profile's own
    drive replayed (:func:`drive_replayed`, or `replayed` where the caller has it), on calibration's contact-free
    stretches (cut where a replayed robot touches something)."""
    record, replay = replayed or drive_replayed(recording, profile_file, settings, deliveries)
    tracks = replayed_tracks(record.tracks, replay)
    fit = estimate_actuation(tracks, settings, np.random.default_rng(settings.seed))
    out: dict[str, float | None] = {}
    for key, field_name in REPLAYED.items():
        est = getattr(fit, field_name)
        out[key] = float(est.value) if est.ok and est.value is not None else None
    return out


def jumps(record: Path) -> list[tuple[int, int]]:
    """The host stalls the twin jumped over, (start ns, ns skipped) on its clock (none in a record without them)."""
    if not record.is_file():
        return []
    with np.load(record) as data:
        if "jump_ns" not in data:
            return []
        return [(int(a), int(b)) for a, b in zip(data["jump_ns"], data["jump_skipped_ns"], strict=True)]


def _jumped(record: Path) -> str:
    """Words for the host stalls the twin jumped over (its world frozen through them, and the drive's replay too)."""
    skipped = [b for _, b in jumps(record)]
    if not skipped:
        return ""
    return f"; the twin jumped {len(skipped)} host stall(s), {sum(skipped) / 1e9:.2f} s frozen"


def truth_of(profile: dict[str, Any], key: str) -> float | None:
    """The profile's true value behind a calibrated key (None where the profile has none)."""
    group, _, rest = key.partition(".")
    if key == "actuation.linear_gain":
        base = profile["base"]
        k = float(base["wheel_radius_left_m"] + base["wheel_radius_right_m"]) / (2 * NOMINAL_WHEEL_RADIUS_M)
        return float(profile["actuation"]["linear_gain"]) * k
    if key == "actuation.angular_gain":
        base = profile["base"]
        k = float(base["wheel_radius_left_m"] + base["wheel_radius_right_m"]) / (2 * NOMINAL_WHEEL_RADIUS_M)
        return float(profile["actuation"]["angular_gain"]) * k * 0.281 / float(base["wheel_separation_m"])
    if rest.startswith("mount_xy_m["):
        return float(profile["lidar"]["mount_xy_m"][int(rest[-2])])
    if rest.startswith("box_offsets_m["):
        b, i = int(rest[len("box_offsets_m[")]), int(rest[-2])
        return float(profile["map"]["box_offsets_m"][b][i])
    value = profile.get(group, {}).get(rest)
    return None if value is None else float(value)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--policy", type=Path, default=Path("models/nominal/policy"))
    parser.add_argument(
        "--drive",
        choices=("policy", "excitation"),
        default="policy",
        help="policy: the policy drives; excitation: the calibration drive over it (pipeline.policy.excitation)",
    )
    parser.add_argument("--fleet", default="twin")
    parser.add_argument("--profiles", type=int, default=20)
    parser.add_argument("--episodes", type=int, default=10)
    parser.add_argument("--time-scale", type=float, default=3.0)
    parser.add_argument("--seed", type=int, default=100)
    parser.add_argument(
        "--ranges",
        choices=("wide", "drawn"),
        default="wide",
        help="wide: the ranges of real robots (pipeline.twin.draw.WIDE_RANGES); drawn: the sim2real benchmark's",
    )
    parser.add_argument(
        "--reality",
        metavar="PROFILE",
        help="no drawing: every recording against this reality profile (bundled name or YAML path), as the loop's "
        "deployment has it (the loop's own recordings: --reality lab --episodes 50, seeds as the deploy stage's)",
    )
    parser.add_argument("--out", type=Path, default=Path("logs/benchmarks/calibration_coverage.csv"))
    where = parser.add_mutually_exclusive_group()
    where.add_argument("--keep", type=Path, help="keep profiles and recordings in this folder")
    where.add_argument("--recalibrate", type=Path, help="calibrate the recordings of a --keep run again")
    where.add_argument(
        "--pool",
        type=Path,
        nargs="+",
        metavar="CSV",
        help="deploy and calibrate nothing: the summary over the rows of these runs' CSVs together (other profiles)",
    )
    parser.add_argument(
        "--parts", nargs="+", choices=PARTS, default=list(PARTS), help="with --recalibrate: the parts calibrated"
    )
    args = parser.parse_args()
    if args.pool is not None:
        return _pool(args.pool)
    if args.recalibrate is None and list(args.parts) != list(PARTS):
        print("calibration_coverage: --parts goes with --recalibrate (a deployment is calibrated whole)")
        return 2
    if args.recalibrate is not None:
        missing = [
            f"drawn_{args.seed + p}.{ext}"
            for p in range(args.profiles)
            for ext in ("yaml", "mcap")
            if not (args.recalibrate / f"drawn_{args.seed + p}.{ext}").is_file()
        ]
        if missing:
            print(f"calibration_coverage: --recalibrate {args.recalibrate} lacks {', '.join(missing[:4])}")
            return 2
        return _recalibrate(args)
    if not (args.policy / "policy.json").is_file():
        print(f"calibration_coverage: no exported policy at {args.policy} (run `dvc repro` first or pass --policy)")
        return 2
    runtime = PolicyRuntime(args.policy)
    fleet = load_fleet(args.fleet)
    scenario = load_scenario(fleet.scenario)
    fixed: dict[str, Any] | None = None
    if args.reality is not None:
        try:
            load_profile_for(args.reality, scenario)
        except MrlError as e:
            print(f"calibration_coverage: --reality {args.reality}: {e}")
            return 2
        fixed = yaml.safe_load(profile_path(args.reality).read_text(encoding="utf-8"))
    args.out.parent.mkdir(parents=True, exist_ok=True)
    rows: list[dict[str, object]] = []
    if args.keep is not None:
        args.keep.mkdir(parents=True, exist_ok=True)
    folder = nullcontext(str(args.keep)) if args.keep is not None else tempfile.TemporaryDirectory()
    with folder as tmp, args.out.open("w", newline="") as f:
        writer = csv.DictWriter(f, COLUMNS)
        writer.writeheader()
        for p in range(args.profiles):
            seed = args.seed + p
            ranges = WIDE_RANGES if args.ranges == "wide" else PROFILE_RANGES
            mapping = fixed if fixed is not None else draw_profile_mapping(seed, len(scenario.obstacles), ranges)
            path = Path(tmp) / f"drawn_{seed}.yaml"
            path.write_text(yaml.safe_dump(mapping), encoding="utf-8")
            recording = Path(tmp) / f"drawn_{seed}.mcap"
            start = time.perf_counter()
            request = DeployRequest(
                episodes=args.episodes,
                seed=20000 + 100 * p,
                recording=recording,
                time_scale=args.time_scale,
                profile=str(path),
                progress=False,
            )
            deliveries = Path(tmp) / f"drawn_{seed}.link.npz"
            driver: Any = runtime if args.drive == "policy" else ExcitationDrive(runtime, seed=20000 + 100 * p)
            deploy_policy(driver, fleet, args.fleet, request, twin_extra_args=["--link-record", str(deliveries)])
            for row in _scored(recording, mapping, seed, path):
                rows.append(row)
                writer.writerow(row)
            f.flush()
            print(
                f"profile {p + 1}/{args.profiles} (seed {seed}) done in {time.perf_counter() - start:.0f} s"
                + _jumped(deliveries),
                file=sys.stderr,
                flush=True,
            )
    summary(rows)
    return 0


CATEGORIES = ("lidar.no_return",)
"""Keys that are a choice, not a number: scored as found or not, outside the coverage figures."""
COLUMNS = ["profile", "key", "truth", "truth_of", "profile_truth", "value", "low", "high", "covered", "rel_error"]


def _scored(
    recording: Path, mapping: dict[str, Any], seed: int, profile_file: Path, parts: tuple[Part, ...] = PARTS
) -> list[dict[str, object]]:
    """Calibrate one recording and score every estimated key against the truth: the profile's, or for `REPLAYED`
    what the key stands for on this recording."""
    settings = CalibrationSettings(bootstrap=200, seed=seed, parts=parts)
    cal = calibrate(recording, settings)
    deliveries = recording.with_suffix(".link.npz")
    realized: dict[str, float | None] = {}
    replayed: dict[str, float | None] = {}
    if "actuation" in parts:
        drive = drive_replayed(recording, profile_file, settings, deliveries)
        replayed = drive_truths(recording, profile_file, settings, deliveries, drive)
        applied = applied_commands(deliveries) if deliveries.is_file() else None
        path = command_path_s(drive[0].sessions[0], applied) if applied else None
        delay = truth_of(mapping, "actuation.delay_s")
        if path is not None and delay is not None:
            realized["actuation.delay_s"] = delay + path[0]
    if deliveries.is_file():
        realized["network.jitter_s"] = realized_jitter(deliveries)
    rows: list[dict[str, object]] = []
    if cal.lidar is not None and cal.lidar.no_return is not None:  # a category: found or not
        truth = str(mapping.get("lidar", {}).get("no_return", "inf"))
        found = cal.lidar.no_return
        rows.append({"profile": seed, "key": "lidar.no_return", "truth": truth, "truth_of": "profile",
                     "profile_truth": truth, "value": found, "covered": int(found == truth)})  # fmt: skip
    scored = [(key, est, truth_of(mapping, key)) for key, est in cal.values.items()]
    # the noise at the range the data determine, from the still spans and from the scans while driving
    sigma, per_m = truth_of(mapping, "lidar.noise_sigma_m"), truth_of(mapping, "lidar.noise_per_m") or 0.0
    if cal.lidar is not None and sigma is not None:
        determined = [("lidar.noise_at_range", cal.lidar.noise_at_range)]
        if cal.lidar.noise_driving is not None:
            determined.append(("lidar.noise_at_range_driving", cal.lidar.noise_driving.at_range))
        for key, at in determined:
            if at is not None:
                scored.append((key, at[1], sigma + per_m * at[0]))
    scored += [(f"effective.{name}", value.estimate, None) for name, value in cal.effective.items()]
    for key, est, profile_truth in scored:
        kind, truth = "profile", profile_truth
        if key in REPLAYED:
            kind, truth = "replay", replayed.get(key)
        elif realized.get(key) is not None:
            kind, truth = "realized", realized[key]
        if truth is None:
            continue
        row: dict[str, object] = {
            "profile": seed,
            "key": key,
            "truth": truth,
            "truth_of": kind,
            "profile_truth": "" if profile_truth is None else profile_truth,
        }
        if est.ok and est.value is not None and est.interval is not None:
            lo, hi = est.interval
            row.update(
                value=est.value,
                low=lo,
                high=hi,
                covered=int(lo <= truth <= hi),
                rel_error=abs(est.value - truth) / abs(truth) if truth != 0 else math.nan,
            )
        rows.append(row)
    return rows


def _recalibrate(args: argparse.Namespace) -> int:
    """Score the calibration of recordings kept by an earlier run (no deployment)."""
    args.out.parent.mkdir(parents=True, exist_ok=True)
    rows: list[dict[str, object]] = []
    with args.out.open("w", newline="") as f:
        writer = csv.DictWriter(f, COLUMNS)
        writer.writeheader()
        for p in range(args.profiles):
            seed = args.seed + p
            mapping = yaml.safe_load((args.recalibrate / f"drawn_{seed}.yaml").read_text(encoding="utf-8"))
            start = time.perf_counter()
            profile_file = args.recalibrate / f"drawn_{seed}.yaml"
            for row in _scored(args.recalibrate / f"drawn_{seed}.mcap", mapping, seed, profile_file, tuple(args.parts)):
                rows.append(row)
                writer.writerow(row)
            f.flush()
            print(
                f"profile {p + 1}/{args.profiles} (seed {seed}) calibrated in {time.perf_counter() - start:.0f} s",
                file=sys.stderr,
                flush=True,
            )
    summary(rows)
    return 0


def _pool(files: list[Path]) -> int:
    """The summary over several runs' rows (their profiles must differ: a profile in two files is refused)."""
    rows: list[dict[str, object]] = []
    seen: dict[str, Path] = {}
    for path in files:
        if not path.is_file():
            print(f"calibration_coverage: --pool: {path} does not exist")
            return 2
        with path.open(newline="") as f:
            mine = list(csv.DictReader(f))
        if not mine or set(COLUMNS) - set(mine[0]):
            print(f"calibration_coverage: --pool: {path} is not a coverage CSV (columns: {', '.join(COLUMNS)})")
            return 2
        for profile in sorted({str(r["profile"]) for r in mine}):
            if profile in seen:
                print(f"calibration_coverage: --pool: profile {profile} is in both {seen[profile]} and {path}")
                return 2
            seen[profile] = path
        rows += [{k: v for k, v in r.items() if v != ""} for r in mine]
    print(f"{len(seen)} profiles from {len(files)} runs")
    summary(rows)
    return 0


NOMINAL = 0.95
"""What every interval claims: the share of drawn realities whose truth it holds."""
TOO_SURE_LEVEL = 0.05
"""A key's intervals are called too sure where so few of them hold the truth that, were they 95 % intervals, so few
or fewer would happen with probability under this level divided by the keys tested (Bonferroni over the keys)."""


def coverage_test(covered: int, n: int, keys: int) -> tuple[float, float, float, bool]:
    """(low, high, p, too_sure) for `covered` of `n` intervals holding the truth: the Clopper-Pearson 95 % interval
    of the coverage, the one-sided binomial probability of `covered` or fewer were the coverage `NOMINAL`, and
    whether that is under `TOO_SURE_LEVEL` / `keys`. With 20 realities a key whose intervals are exact 95 % ones
    falls under 90 % with probability 0.075 (18 or fewer of 20), so of 29 such keys two would; the per-key 90 %
    target reads such chance as failure, this test does not."""
    from scipy import stats as st

    low = float(st.beta.ppf(0.025, covered, n - covered + 1)) if covered > 0 else 0.0
    high = float(st.beta.ppf(0.975, covered + 1, n - covered)) if covered < n else 1.0
    p = float(st.binom.cdf(covered, n, NOMINAL))
    return low, high, p, p < TOO_SURE_LEVEL / max(keys, 1)


def _weak(row: dict[str, object]) -> bool:
    """An interval wider than its value (half-width over the value's size): calibration's "weakly determined"."""
    try:
        value, low, high = float(row["value"]), float(row["low"]), float(row["high"])  # type: ignore[arg-type]
    except (KeyError, TypeError, ValueError):
        return False
    return (high - low) / 2 > abs(value)


def summary(rows: list[dict[str, object]]) -> None:
    """Per key: how often it was identified, its interval's coverage of the truth (with its Clopper-Pearson 95 %
    interval, and whether the intervals are significantly too sure for 95 % ones: `coverage_test`), its median
    relative error (over every estimate and over the well-determined ones: interval narrower than the value) and
    median interval half-width; the verdict against the targets (every key >= 90 % covered; identifiable keys
    within 15 % in the median), the keys too sure, and the coverage pooled over every interval."""
    keys, rows = split_by_truth(rows)  # pooled runs that scored a key against different truths: one line per truth
    print(
        f"{'key':34s} {'kind':10s} {'identified':>10s} {'coverage':>8s} {'95 % of it':>13s} {'med rel err':>11s} "
        f"{'determined':>10s} {'med half-width':>14s}"
    )
    scored = [k for k in keys if k not in CATEGORIES and any(r["key"] == k and "covered" in r for r in rows)]
    worst, at_target, counted, close, identifiable, sure, too_sure = 1.0, 0, 0, 0, 0, 0, []
    determined_close, determined_n = 0, 0
    pooled_hit, pooled_n = 0, 0
    for key in keys:
        mine = [r for r in rows if r["key"] == key]
        if key in CATEGORIES:
            found = sum(int(r["covered"]) for r in mine)  # type: ignore[call-overload]
            print(f"{key:34s} {'category':10s} {len(mine):>4d}/{len(mine):<5d} found the truth in {found}/{len(mine)}")
            continue
        ok = [r for r in mine if "covered" in r]
        realized = any(r.get("truth_of") == "realized" for r in mine)
        base = key.split(" ")[0]
        kind = "replayed" if base in REPLAYED else "effective" if base in EFFECTIVE else (
            "identif." if base in IDENTIFIABLE or "box" in base else "other"
        )  # fmt: skip
        if realized:  # an identifiable key scored against what the run realized stays identifiable
            kind = "realized" if kind != "identif." else "identif.r"
        if not ok:
            print(f"{key:34s} {kind:10s} {0:>4d}/{len(mine):<5d} {'-':>8s}")
            continue
        hits = sum(int(r["covered"]) for r in ok)  # type: ignore[call-overload]
        cov = hits / len(ok)
        low, high, _, flagged = coverage_test(hits, len(ok), len(scored))
        rel = [float(r["rel_error"]) for r in ok if math.isfinite(float(r["rel_error"]))]  # type: ignore[arg-type]
        firm = [
            float(r["rel_error"])  # type: ignore[arg-type]
            for r in ok
            if not _weak(r) and math.isfinite(float(r["rel_error"]))  # type: ignore[arg-type]
        ]
        half = float(np.median([(float(r["high"]) - float(r["low"])) / 2 for r in ok]))  # type: ignore[arg-type]
        med = f"{np.median(rel):.3f}" if rel else "-"
        firm_text = f"{np.median(firm):.3f} ({len(firm)})" if firm else "- (0)"
        mark = " too sure" if flagged else ""
        print(
            f"{key:34s} {kind:10s} {len(ok):>4d}/{len(mine):<5d} {cov:8.2f} [{low:.2f}, {high:.2f}] {med:>11s} "
            f"{firm_text:>10s} {half:14.4g}{mark}"
        )
        worst = min(worst, cov)
        counted += 1
        at_target += cov >= 0.9
        pooled_hit, pooled_n = pooled_hit + hits, pooled_n + len(ok)
        if flagged:
            too_sure.append(key)
        sure += not flagged
        if kind.startswith("identif.") and rel:
            identifiable += 1
            close += float(np.median(rel)) <= 0.15
            if firm:
                determined_n += 1
                determined_close += float(np.median(firm)) <= 0.15
    p_low, p_high, _, _ = coverage_test(pooled_hit, pooled_n, 1) if pooled_n else (math.nan, math.nan, 0.0, False)
    print(
        f"coverage pooled over {pooled_n} intervals: {pooled_hit / max(pooled_n, 1):.3f} [{p_low:.3f}, {p_high:.3f}]; "
        f"too sure for 95 % intervals (one-sided binomial, {TOO_SURE_LEVEL:g} over {counted} keys): "
        + (", ".join(too_sure) if too_sure else "none")
    )
    print(
        f"coverage_min={worst:.2f} keys_at_target={at_target}/{counted} "
        f"identifiable_within_15pct={close}/{identifiable} keys_consistent_with_95={sure}/{counted} "
        f"determined_within_15pct={determined_close}/{determined_n} "
        f"pooled_coverage={pooled_hit / max(pooled_n, 1):.3f}"
    )


if __name__ == "__main__":
    sys.exit(main())
