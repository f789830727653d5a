"""The result tables of README.md and docs/, and the figures in their sentences, made from committed result files.

Each block between ``<!-- results: NAME -->`` and ``<!-- /results -->`` in the pages of :data:`FILES` (README.md's
headline, docs/results.md, and the docs pages whose text a block belongs to) is written by one function below from
files under ``benchmarks/results/`` (a folder's ``run.json`` names its command, commit, machine and date; the layout,
pursuit and first ten-robot folders were recorded before run.json existed, and the text around their table gives
their commands). A block's links are relative to the page that holds it. Nothing in a block is typed by hand:

    python benchmarks/readme_tables.py            # rewrite the blocks from the result files
    python benchmarks/readme_tables.py --check    # exit 1 naming every block that differs from its files

``tests/unit/test_readme_tables.py`` runs the check, so a table that disagrees with its result file fails the tests.
"""

from __future__ import annotations

import argparse
import json
import re
import statistics
import sys
import textwrap
from collections.abc import Callable
from functools import partial
from pathlib import Path
from typing import Any

import yaml
from coverage_keys import split_by_truth

from pipeline.core.stats import newcombe_interval
from pipeline.params import read_calibration_file
from pipeline.record.results import SessionMetrics, read_episodes_csv, read_session_metrics

ROOT = Path(__file__).resolve().parents[1]
CATEGORIES = ("lidar.no_return",)
"""Coverage rows that score a choice (found or not), not an interval."""

RESULTS = ROOT / "benchmarks" / "results"
BLOCK = re.compile(r"(<!-- results: (?P<name>[a-z0-9-]+) -->\n)(?P<body>.*?)(<!-- /results -->)", re.S)


def pct(x: float) -> str:
    """A rate in percent, one decimal ("100 %" and "0 %" at the ends)."""
    return "100 %" if x >= 1.0 else "0 %" if x <= 0.0 else f"{100 * x:.1f} %"


def prose(*parts: str) -> str:
    """A paragraph wrapped at the README's width (links and numbers are never broken)."""
    text = "".join(parts).replace(" %", "\x00%")  # "65.0 %" stays on one line
    return textwrap.fill(text, width=118, break_long_words=False, break_on_hyphens=False).replace("\x00", " ")


def interval(rate: Any) -> str:
    return f"[{100 * rate.ci_low:.1f}, {100 * min(rate.ci_high, 1.0):.1f}]".replace("100.0]", "100]")


def rate_text(metrics: SessionMetrics) -> str:
    return f"{pct(metrics.robot_success.value)} {interval(metrics.robot_success)}"


def gap_text(sim: SessionMetrics, real: SessionMetrics, robots: int) -> str:
    """sim - real robot success in points with its Newcombe 95 % interval (every episode counted)."""
    n_sim, n_real = sim.episodes * robots, real.episodes * robots
    k_sim, k_real = round(sim.robot_success.value * n_sim), round(real.robot_success.value * n_real)
    low, high = newcombe_interval(k_sim, n_sim, k_real, n_real)
    gap = sim.robot_success.value - real.robot_success.value
    return f"{100 * gap:+.1f} points [{100 * low:+.1f}, {100 * high:+.1f}]"


def aborted_text(metrics: SessionMetrics) -> str:
    return f"{metrics.aborted_episodes} of {metrics.episodes}"


def stale_text(metrics: SessionMetrics) -> str:
    return ", ".join(f"{s:.1f}" for s in metrics.stale_s_each)


def last_figures(text: str) -> dict[str, str]:
    """The ``key=value`` figures of a benchmark's last printed line."""
    return dict(pair.split("=", 1) for pair in text.strip().splitlines()[-1].split())


def run_of(folder: Path) -> dict[str, Any]:
    return dict(json.loads((folder / "run.json").read_text(encoding="utf-8")))


def loop_lab() -> str:
    folder = RESULTS / "loop" / "lab"
    logs = folder / "logs"
    run = run_of(folder)
    rows = []
    for name in ("nominal", "calibrated"):
        sim = read_session_metrics(logs / "sim" / name / "metrics.json", "eval")
        real = read_session_metrics(logs / "real" / name / "metrics.json", "real")
        robots = len(real.robot_success_each)
        rows.append(
            f"| {name} | {rate_text(sim)} / {pct(sim.team_success.value)} | {rate_text(real)} / "
            f"{pct(real.team_success.value)} | {aborted_text(real)} | {gap_text(sim, real, robots)} | "
            f"{stale_text(real)} |"
        )
    cal = read_calibration_file(logs / "calibration" / "calibration.yaml")
    truth = yaml.safe_load((ROOT / "pipeline" / "twin" / "profiles" / "lab.yaml").read_text(encoding="utf-8"))
    replay = json.loads((logs / "replay" / "replay.json").read_text(encoding="utf-8"))
    calibrated = read_session_metrics(logs / "real" / "calibrated" / "metrics.json", "real")
    sim_cal = read_session_metrics(logs / "sim" / "calibrated" / "metrics.json", "eval")
    gap_cal = 100 * (sim_cal.robot_success.value - calibrated.robot_success.value)
    trained = json.loads((folder / "models" / "nominal" / "train_metrics.json").read_text(encoding="utf-8"))
    steps = f"{int(trained['train/world_steps']):,}".replace(",", " ")

    def est(key: str) -> float:
        value = cal.keys[key].value
        return float("nan") if value is None else value

    return "\n".join(
        [
            prose(
                f"**The loop on the `lab` twin** (`{run['command']}` with the defaults: PPO, {steps} steps, one "
                "network shared by the three robots; 200 sim and 50 twin episodes per round; "
                "[benchmarks/results/loop/lab/](benchmarks/results/loop/lab/run.json), "
                f"{run['wall_s']:.0f} s end to end on 2 cores at {run['commit'][:7]}; {stage_line(logs / 'stages')}; "
                f"{scales_line(logs / 'real')}):"
            ),
            "",
            "| round | sim at its values, robot / team | twin (`lab`), robot / team | aborted | gap sim - twin "
            "| stale s per robot (twin) |",
            "|---|---|---|---|---|---|",
            *rows,
            "",
            prose(
                "A robot whose scans stop in one of the lab network's loss bursts stands still until fresh data comes "
                "while the others drive on; only a robot blind for 5 s would abort an episode. The calibration found "
                f"the network as it is (loss {est('network.loss_prob'):.3f} for {truth['network']['loss_prob']:g}, "
                f"bursts of {est('network.burst_len'):.1f} for {truth['network']['burst_len']:g}, an "
                f"{est('lidar.rate_hz'):.1f} Hz lidar, clock drift {est('clock.drift_ppm'):.0f} ppm for "
                f"{truth['clock']['drift_ppm']:g}) and the calibrated round trained in it: "
                + gap_sentence(gap_cal, logs / "real" / "calibrated" / "episodes.csv")
                + " Replaying the nominal deployment's commands open loop, the "
                f"nominal simulator is {replay['replay/nominal_commands_in_nominal_sim/error_10s_m']:.3f} m off the "
                "recorded path after 10 s, the calibrated one "
                f"{replay['replay/nominal_commands_in_calibrated_sim/error_10s_m']:.3f} m "
                "([replay.md](benchmarks/results/loop/lab/logs/replay/replay.md)).",
            ),
        ]
    )


LOOP_GAP_TARGET = 3.0
"""Points: the calibrated simulator predicts the twin when its robot success is within this of the twin's."""


def stage_line(folder: Path) -> str:
    """The stage table in words: seconds of the stages that took most of the run, the rest summed."""
    seconds: dict[str, float] = {}
    for path in folder.glob("*.json"):
        record = json.loads(path.read_text(encoding="utf-8"))
        name = str(record["stage"]).partition("@")[0]
        seconds[name] = seconds.get(name, 0.0) + float(record["seconds"])
    if not seconds:
        return "no stage table"
    big = sorted((k for k, v in seconds.items() if v >= 60), key=lambda k: -seconds[k])
    rest = sum(v for k, v in seconds.items() if k not in big)
    return "stages: " + ", ".join(f"{k} {seconds[k]:.0f} s" for k in big) + f", the other {rest:.0f} s"


def scales_line(folder: Path) -> str:
    """The time scales the twin was asked for per round (from each round's episodes.csv) and how many episodes kept
    their clock."""
    parts = []
    kept = total = 0
    for name in ("nominal", "calibrated"):
        rows = read_episodes_csv(folder / name / "episodes.csv")
        by_episode = {int(r["episode"]): r for r in rows}
        asked = sorted({float(r["time_scale_asked"]) for r in by_episode.values()})
        kept += sum(int(r["clock_kept"]) for r in by_episode.values())
        total += len(by_episode)
        span = f"{asked[0]:g}x" if len(asked) == 1 else f"{asked[0]:g}-{asked[-1]:g}x"
        parts.append(f"{name} {span}")
    return f"the twin at the time scale asked ({', '.join(parts)}), its clock kept in {kept} of {total} episodes"


def gap_sentence(gap_points: float, episodes_csv: Path) -> str:
    """Whether the calibrated simulator predicts the twin (within :data:`LOOP_GAP_TARGET` points), and where it does
    not, the robot that fails on the twin and how."""
    if abs(gap_points) <= LOOP_GAP_TARGET:
        return f"its simulator predicts the twin within {abs(gap_points):.1f} points."
    rows = read_episodes_csv(episodes_csv)
    robots = sorted({str(r["robot"]) for r in rows})
    worst = min(robots, key=lambda name: sum(bool(r["success"]) for r in rows if r["robot"] == name))
    mine = [r for r in rows if r["robot"] == worst]
    collided = sum(bool(r["collided"]) for r in mine)
    return (
        f"its simulator does not predict the twin: {gap_points:+.1f} points, beyond the {LOOP_GAP_TARGET:g} aimed at; "
        f"on the twin {worst} collided in {collided} of {len(mine)} episodes "
        "([docs/experiments/calibrated-collision.md](docs/experiments/calibrated-collision.md))."
    )


def _curvature_per_m(base: dict[str, float]) -> float:
    """How far unequal wheels turn a straight command: rad per metre driven."""
    left, right = base["wheel_radius_left_m"], base["wheel_radius_right_m"]
    return 2 * (right - left) / (base["wheel_separation_m"] * (right + left))


def sim2real() -> str:
    folder = RESULTS / "sim2real"
    rows = []
    notes = []
    for spec in ("drawn_26", "drawn_79"):
        base = folder / spec
        truth = yaml.safe_load((base / "profile.yaml").read_text(encoding="utf-8"))
        name = spec.replace("_", ":")
        net = truth["network"]
        label = (
            f"{name} ({truth['lidar']['rate_hz']:.1f} Hz lidar, loss {100 * net['loss_prob']:.1f} % in bursts of "
            f"{net['burst_len']:.1f})"
        )
        for round_name in ("nominal", "calibrated"):
            sim = read_session_metrics(base / "sim" / round_name / "metrics.json", "eval")
            real = read_session_metrics(base / "real" / round_name / "metrics.json", "real")
            robots = len(real.robot_success_each)
            rows.append(
                f"| {label if round_name == 'nominal' else name} | {round_name} | {rate_text(sim)} | "
                f"{rate_text(real)} / {pct(real.team_success.value)} | {aborted_text(real)} | "
                f"{gap_text(sim, real, robots)} |"
            )
        cal = read_calibration_file(base / "calibration" / "calibration.yaml")
        notes.append((name, truth, cal))
    name, truth, cal = notes[1]
    nominal = read_session_metrics(folder / "drawn_79" / "real" / "nominal" / "metrics.json", "real")
    calibrated = read_session_metrics(folder / "drawn_79" / "real" / "calibrated" / "metrics.json", "real")
    sim_cal = read_session_metrics(folder / "drawn_79" / "sim" / "calibrated" / "metrics.json", "eval")
    gain = cal.keys["actuation.angular_gain"].value or float("nan")
    return "\n".join(
        [
            prose(
                "**Realities drawn at random** (`python benchmarks/sim2real.py --profiles drawn:26 drawn:79`: the "
                "first two drawn profiles whose network loses >= 4 % of its messages in bursts of >= 4, the loop's "
                "nominal policy, 200 sim and 50 twin episodes per round; "
                "[benchmarks/results/sim2real/](../benchmarks/results/sim2real/summary.txt)):"
            ),
            "",
            "| reality | round | sim at its values | twin, robot / team | aborted | gap sim - twin |",
            "|---|---|---|---|---|---|",
            *rows,
            "",
            prose(
                f"The nominal policy reaches {pct(nominal.robot_success.value)} on {name} because its robots are "
                "outside what the nominal round randomized: unequal wheels that curve a straight command by "
                f"{_curvature_per_m(truth['base']):+.3f} rad/m (the nominal range is +-0.1) and an angular gain of "
                f"{truth['actuation']['angular_gain']:.2f} ({gain:.2f} at the body as calibrated; the nominal range "
                "is 0.8 to 1.1). Calibrated on that reality's own recording, the simulator predicts it within "
                f"{100 * abs(sim_cal.robot_success.value - calibrated.robot_success.value):.1f} points and the "
                f"policy reaches {pct(calibrated.robot_success.value)}."
            ),
        ]
    )


def ten() -> str:
    folder = RESULTS / "ten" / "dagger_every_episode" / "s1"
    logs = folder / "logs" / "benchmarks" / "ten_lab_1x"
    twin = read_session_metrics(logs / "twin" / "metrics.json", "real")
    sim = read_session_metrics(logs / "sim_random" / "metrics.json", "eval")
    summary = (folder / "summary.txt").read_text(encoding="utf-8")
    timing = re.search(r"tick jitter p99 ([0-9.]+) ms .*send skew p99 ([0-9.]+) ms", summary)
    if timing is None:
        raise SystemExit(f"{folder / 'summary.txt'}: no 'twin timing' line")
    weak = [f"robot_{i + 1}" for i, s in enumerate(twin.robot_success_each) if s <= 0.25]
    low = min(twin.robot_success_each)
    high = max(s for s in twin.robot_success_each if s <= 0.25)
    return prose(
        "**Ten robots on the `lab` twin at 1x** (the path teacher's student of "
        f"`benchmarks/settings/ten_dagger.yaml`, seed 1; {twin.episodes} episodes on the same seeds in sim and on the "
        "twin; "
        "[benchmarks/results/ten/dagger_every_episode/s1/](../benchmarks/results/ten/dagger_every_episode/s1/run.json)):"
        f" twin {rate_text(twin)} over every episode, {twin.aborted_episodes} aborted (the simulator "
        f"{rate_text(sim)} on the same seeds; team {pct(twin.team_success.value)} on the twin, "
        f"{pct(sim.team_success.value)} in sim: on the twin {', '.join(weak)} arrive in "
        f"{100 * low:.0f} to {100 * high:.0f} % of the episodes); emitter tick jitter p99 "
        f"{timing.group(1)} ms and cross-robot send skew p99 {timing.group(2)} ms (targets 1 and 0.5 ms)."
    )


def recount() -> str:
    data = json.loads((RESULTS / "recount.json").read_text(encoding="utf-8"))
    rows = {Path(r["folder"]).parts[3]: r for r in data["rows"]}
    ten_row, memory = rows["dagger"], rows["memory5_dropout25"]

    def sentence(row: dict[str, Any]) -> str:
        completed = row["episodes"] - row["aborted_episodes"]
        return (
            f"{pct(row['robot_success'])} [{100 * row['robot_success_ci_low']:.1f}, "
            f"{100 * row['robot_success_ci_high']:.1f}] over all {row['episodes']:.0f} episodes "
            f"({pct(row['robot_success_completed_as_reported'])} over the {completed:.0f} completed)"
        )

    return prose(
        "**Re-counted with every episode** ([benchmarks/results/recount.json](../benchmarks/results/recount.json), "
        "from the committed episodes of runs made while aborted episodes were left out): the ten-robot student on the "
        f"lab twin at 1x, {sentence(ten_row)}; the quarter-dropout memory student of seed 3 on random layouts, "
        f"{sentence(memory)}. Older twin figures in docs/ that name aborted episodes beside them are completed-only "
        "rates, marked as such there."
    )


def busy_host() -> str:
    folder = RESULTS / "busy_host"
    run = run_of(folder)
    m = {name: json.loads((folder / name / "metrics.json").read_text(encoding="utf-8")) for name in run["wall_s"]}

    def kept(name: str) -> str:
        x = m[name]
        return f"{x['real/clock_kept_episodes']:.0f} of {x['real/episodes']:.0f}"

    def success(name: str) -> str:
        x = m[name]
        low, high = 100 * x["real/robot_success_ci_low"], 100 * x["real/robot_success_ci_high"]
        return f"{pct(x['real/robot_success'])} [{low:.1f}, {high:.1f}]"

    auto = m["busy-auto"]
    return prose(
        f"**A busy host** ([results/busy_host/](../benchmarks/results/busy_host/run.json), `python "
        f"benchmarks/busy_host.py --load 6` at {run['commit'][:7]}: the nominal policy on the lab twin, 20 episodes, "
        "6 processes spinning beside it on the 2 cores): the deployment kept its clock in "
        f"{kept('quiet')} episodes at 3x on the quiet host, {kept('busy')} at 3x beside the load (control steps up "
        f"to {m['busy']['real/control_late_p95_max']:.2f} of a period late, 95th percentile, against "
        f"{m['quiet']['real/control_late_p95_max']:.2f} quiet), {kept('busy-auto')} at `--time-scale auto` (from "
        f"{auto['real/time_scale_asked_max']:g}x down to {auto['real/time_scale_asked_min']:g}x, "
        f"{run['wall_s']['busy-auto']:.0f} s against {run['wall_s']['busy']:.0f} s); robot success "
        f"{success('quiet')}, {success('busy')}, {success('busy-auto')}."
    )


def scale() -> str:
    folder = RESULTS / "calibration_scale"
    text = (folder / "summary.txt").read_text(encoding="utf-8")
    cells = re.search(r"map: (\d+) x (\d+) cells at ([0-9.]+) m, (\d+) faces", text)
    bag = re.search(r"bag: (\d+) s, .* (\d+) scans of (\d+) beams", text)
    last = last_figures(text)
    if cells is None or bag is None:
        raise SystemExit(f"{folder / 'summary.txt'}: not the output of benchmarks/calibration_scale.py")
    side = int(cells.group(1)) * float(cells.group(3))
    windows = re.search(r"\((\d+) windows of (\d+) s\)", text)
    drift = {
        m.group(1): (m.group(2), m.group(3))
        for m in re.finditer(r"\| (\d+) s \| ([0-9.]+) m \([0-9.]+ m\) \| ([0-9.]+) m", text)
    }
    walls = re.search(r"met a wall of the map \| (\d+) of \d+ windows \| (\d+) of \d+ windows", text)
    if windows is None or "30" not in drift or walls is None:
        raise SystemExit(
            f"{folder / 'summary.txt'}: no open-loop replay in it (benchmarks/calibration_scale.py prints one)"
        )
    replay = (
        f" The bag's commands open loop against its localized path (`mrl replay BAG --map`, {windows.group(1)} windows "
        f"starting at rest): the nominal simulator drifts {drift['5'][0]} / {drift['10'][0]} / {drift['30'][0]} m "
        f"(mean) at 5 / 10 / 30 s, the calibrated one {drift['5'][1]} / {drift['10'][1]} / {drift['30'][1]} m; a "
        f"simulated robot met a wall of the map in {walls.group(1)} and {walls.group(2)} windows "
        "(the bag's drive, a delay, a lag and gains, is of the simulator's own model class: this checks the "
        "machinery; a real robot's bag is the figure to trust)."
    )
    return prose(
        f"**Calibration at building scale** (`{run_of(folder)['command']}`; "
        "[benchmarks/results/calibration_scale/](../benchmarks/results/calibration_scale/summary.txt)): a generated "
        f"building of {side:.0f} x {side:.0f} m as a map_server map at {cells.group(3)} m ({cells.group(4)} wall "
        f"faces), a {bag.group(1)} s bag of {bag.group(2)} scans of a {bag.group(3)}-beam lidar without motion "
        f"capture, calibrated with the robot localized in the map: peak memory {last['peak_mib']} MiB "
        f"({last['limit_ratio']} of the 2 GiB limit), {last['wall_s']} s ({last['duration_ratio']} of the bag's "
        "duration)." + replay
    )


COVERAGE = "calibration_coverage"
COVERAGE_EXCITATION = "calibration_coverage/excitation"
COVERAGE_RESCORED = "calibration_coverage/policy_rescored"
COVERAGE_EXCITATION_RESCORED = "calibration_coverage/excitation_rescored"
"""The recordings of the two runs above, every part calibrated again with the code named in their run.json."""
COVERAGE_EXCITATION_FINE = "calibration_coverage/excitation_fine"
"""The same realities driven again by the calibration drive with turns of drawn sizes, calibrated as recorded."""
COVERAGE_EXCITATION_FINE_RESCORED = "calibration_coverage/excitation_fine_rescored"
"""Those recordings, every part calibrated again with the code named in its run.json."""
COVERAGE_EXCITATION_FINE_ARC = "calibration_coverage/excitation_fine_signed_arc"
"""Those recordings calibrated again after the odometry took the wheels' arc out by the signed distance and the lidar
masked its beams in the fitted room."""
COVERAGE_EXCITATION_FINE_REFINED = "calibration_coverage/excitation_fine_refined"
"""Those recordings calibrated again after the drive chain's lags were read between the transients' grid values and
the dropout interval took the spans' design effect."""
COVERAGE_EXCITATION_FINE_MORE = "calibration_coverage/excitation_fine_120"
"""20 more realities under the calibration drive, with the command path's realized latency in the delay's truth."""
COVERAGE_EXCITATION_FINE_40 = "calibration_coverage/excitation_fine_40"
"""The refined run's 20 robots and those 20 pooled (``--pool``): 40 drawn robots."""
COVERAGE_POLICY_20 = "calibration_coverage/policy_20"
COVERAGE_REAL_LIDAR = "calibration_coverage/real_lidar"
COVERAGE_REAL_LIDAR_DRIVING = "calibration_coverage/real_lidar_driving"
COVERAGE_REAL_LIDAR_ROBUST = "calibration_coverage/real_lidar_robust_mean"
COVERAGE_REAL_LIDAR_ANGLE = "calibration_coverage/real_lidar_angle_prior"
COVERAGE_REAL_LIDAR_TESTED = "calibration_coverage/tested/real_lidar_robust_mean"
"""The last real-lidar recalibration's rows summarized again with the binomial test against 95 %."""
"""Those recordings' lidar, odometry and network parts again after a beam's mean in a still span was taken without
its far-off returns (and the beams' spread at the degrees of freedom those means leave)."""
COVERAGE_LOOP_LAB = "calibration_coverage/loop_lab"
"""The loop's own recordings: the nominal policy on the lab twin, 50 episodes at 3x, four seeds."""
COVERAGE_LOOP_LAB_RESCORED = "calibration_coverage/loop_lab_rescored"
"""The drawn realities with real lidars (range steps, per-beam noise, mixed pixels, no-return conventions...)."""
LIDAR_LIKE_REAL = "lidar_like_real"
"""Twin recordings like a TurtleBot 4's bag (benchmarks/lidar_like_real.py)."""
"""20 robots under the nominal policy's own drive after the drive chain's refinement (8 and 12, pooled)."""


def _coverage_rows(name: str = COVERAGE) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """A coverage run's record and rows; a pooled folder (``--pool``) holds its runs' folders under ``pooled``."""
    import csv

    folder = RESULTS / name
    run = run_of(folder)
    rows: list[dict[str, Any]] = []
    for source in [folder / part for part in run.get("pooled", [])] or [folder]:
        with (source / "coverage.csv").open(newline="", encoding="utf-8") as f:
            rows += list(csv.DictReader(f))
    return run, rows


def _coverage_table(name: str = COVERAGE) -> list[tuple[str, int, int, float, float]]:
    """Per key: (key, identified, profiles, coverage, median relative error); a key that pooled runs scored against
    different truths is one line per truth, as the benchmark's summary has it. A category (the no-return convention)
    is not an interval: left out here."""
    _, rows = _coverage_rows(name)
    rows = [r for r in rows if r["key"] not in CATEGORIES]
    keys, rows = split_by_truth(rows)
    out = []
    for key in keys:
        mine = [r for r in rows if r["key"] == key]
        ok = [r for r in mine if r["covered"] != ""]
        if not ok:
            out.append((key, 0, len(mine), float("nan"), float("nan")))
            continue
        rel = [float(r["rel_error"]) for r in ok if r["rel_error"] not in ("", "nan")]
        median = statistics.median(rel) if rel else float("nan")
        out.append((key, len(ok), len(mine), sum(int(r["covered"]) for r in ok) / len(ok), median))
    return out


def _coverage_counts(name: str = COVERAGE) -> dict[str, str]:
    """The summary's last line: coverage_min, keys_at_target, identifiable_within_15pct."""
    last = (RESULTS / name / "summary.txt").read_text(encoding="utf-8").strip().splitlines()[-1]
    return dict(item.split("=", 1) for item in last.split())


def coverage_docs(name: str = COVERAGE) -> str:
    run, _ = _coverage_rows(name)
    link = f"../benchmarks/results/{name}"
    counts = _coverage_counts(name)
    lines = [
        f"Measured with `{run['command']}` ([run.json]({link}/run.json), "
        + (f"[summary.txt]({link}/summary.txt)); " if run.get("pooled") else f"[coverage.csv]({link}/coverage.csv)); ")
        + f"keys at >= 90 %: {counts['keys_at_target']}, identifiable keys within 15 %: "
        f"{counts['identifiable_within_15pct']}:",
        "",
        "| key | identified | coverage of the 95 % interval | median relative error |",
        "|---|---|---|---|",
    ]
    for key, ok, total, cov, med in _coverage_table(name):
        if not ok:
            lines.append(f"| `{key}` | 0 of {total} | - | - |")
            continue
        lines.append(f"| `{key}` | {ok} of {total} | {100 * cov:.0f} % | {100 * med:.1f} % |")
    return "\n".join(lines)


def _coverage_line(name: str) -> str:
    """How many keys are at target, the least covered, identifiable keys within 15 %."""
    table = [t for t in _coverage_table(name) if t[1]]
    worst = min(table, key=lambda t: t[3])
    counts = _coverage_counts(name)
    return (
        f"{sum(t[3] >= 0.9 for t in table)} of {len(table)} estimated keys cover the truth in >= 90 % of the "
        f"realities (the least `{worst[0]}`, {100 * worst[3]:.0f} %), identifiable keys within 15 %: "
        f"{counts['identifiable_within_15pct']}"
    )


def _tested_line(name: str) -> str:
    """A summary's test of every key's coverage against 95 % and the coverage pooled over its intervals."""
    lines = (RESULTS / name / "summary.txt").read_text(encoding="utf-8").strip().splitlines()
    pooled = next(line for line in lines if line.startswith("coverage pooled over"))
    counts = _coverage_counts(name)
    consistent, keys = counts["keys_consistent_with_95"].split("/")
    share, rest = pooled.removeprefix("coverage pooled over ").split(": ", 1)[1].split(" ", 1)
    bounds = rest.split(";", 1)[0]
    return (
        f"{consistent} of {keys} keys' coverage consistent with 95 % intervals (a one-sided binomial test, 0.05 "
        f"over the keys), {pooled.split(': ', 1)[0].removeprefix('coverage pooled over ')} pooled: {share} "
        f"{bounds} (Clopper-Pearson)"
    )


def coverage() -> str:
    real = run_of(RESULTS / COVERAGE_REAL_LIDAR)
    angle = run_of(RESULTS / COVERAGE_REAL_LIDAR_ANGLE)
    robust = run_of(RESULTS / COVERAGE_REAL_LIDAR_ROBUST)
    tested = run_of(RESULTS / COVERAGE_REAL_LIDAR_TESTED)
    return prose(
        "**Interval coverage on robots calibration was not drawn for** (realities drawn over the ranges of real "
        "robots, each deployed on the twin and its recording calibrated; [docs/calibration.md](calibration.md"
        "#coverage-of-the-intervals), [docs/lidar.md](lidar.md)). With the lidars real robots have (range steps, "
        "per-beam noise, mixed pixels, no-return conventions, wandering sweeps, lost scans; 20 realities at "
        f"{real['commit']}: `{real['command']}`): "
        + _coverage_line(COVERAGE_REAL_LIDAR)
        + f"; their lidar, odometry and network parts again at {angle['commit'][:7]} (the beams' angle errors "
        "in the geometry's intervals): "
        + _coverage_line(COVERAGE_REAL_LIDAR_ANGLE)
        + f"; and at {robust['commit'][:7]} (a still span's beam means without their far-off returns): "
        + _coverage_line(COVERAGE_REAL_LIDAR_ROBUST)
        + f"; tested at {tested['commit'][:7]} (a per-key 90 % target over 20 realities fails exact 95 % intervals "
        "by chance, a key 0.075 of the time): "
        + _tested_line(COVERAGE_REAL_LIDAR_TESTED)
        + ". With ideal lidars, driven by the policy (20 realities, pooled): "
        + _coverage_line(COVERAGE_POLICY_20)
        + "; driven by the calibration drive with turns of every size (40 realities, pooled): "
        + _coverage_line(COVERAGE_EXCITATION_FINE_40)
        + "."
    )


def _found(name: str, key: str) -> str:
    """How often a category key was found: "k of n"."""
    _, rows = _coverage_rows(name)
    mine = [r for r in rows if r["key"] == key]
    return f"{sum(int(r['covered']) for r in mine)} of {len(mine)}"


def lidar_docs() -> str:
    """docs/lidar.md: the recordings like a real bag, and the drawn realities with real lidars."""
    import csv

    folder = RESULTS / LIDAR_LIKE_REAL
    run = run_of(folder)
    with (folder / "rows.csv").open(newline="", encoding="utf-8") as f:
        rows = list(csv.DictReader(f))
    keys = list(dict.fromkeys(r["key"] for r in rows))
    table = ["| key | identified | weak | interval held the truth |", "|---|---|---|---|"]
    held = tried = 0
    for key in keys:
        mine = [r for r in rows if r["key"] == key]
        judged = [r for r in mine if r["held"] != ""]
        hits = sum(int(r["held"]) for r in judged)
        weak = sum(r["status"] == "weak" for r in mine)
        if key in CATEGORIES:
            table.append(f"| `{key}` (found) | {len(judged)} of {len(mine)} | - | {hits} of {len(judged)} |")
            continue
        held, tried = held + hits, tried + len(judged)
        table.append(f"| `{key}` | {len(judged)} of {len(mine)} | {weak} | {hits} of {len(judged)} |")
    recordings = len({r["recording"] for r in rows})
    coverage = run_of(RESULTS / COVERAGE_REAL_LIDAR)
    link = f"../benchmarks/results/{COVERAGE_REAL_LIDAR}"
    return "\n".join(
        [
            prose(
                f"**Recordings like a TurtleBot 4's bag** (`{run['command']}` at {run['commit']}, "
                f"[run.json](../benchmarks/results/{LIDAR_LIKE_REAL}/run.json), "
                f"[rows.csv](../benchmarks/results/{LIDAR_LIKE_REAL}/rows.csv)): {recordings} recordings of one "
                "robot with a 720-beam lidar at 7.7 Hz, ranges in 2 mm steps, a quarter of the beams without a "
                "return, noise 2-5 mm rising with range, standing still for 10 s, then driving, each under a minute; "
                f"{held} of {tried} intervals held the truth ({100 * held / tried:.0f} %).",
            ),
            "",
            *table,
            "",
            prose(
                f"**Drawn realities with real lidars** (`{coverage['command']}` at {coverage['commit']}: 20 realities "
                "drawn from `WIDE_RANGES`, every artefact above included, each recording calibrated whole at once; "
                f"[run.json]({link}/run.json), [summary.txt]({link}/summary.txt)); the no-return convention found "
                f"in {_found(COVERAGE_REAL_LIDAR, 'lidar.no_return')} recordings; "
                + _coverage_line(COVERAGE_REAL_LIDAR)
                + ":",
            ),
            "",
            coverage_docs(COVERAGE_REAL_LIDAR).split("\n", 2)[2],
            *_again(
                COVERAGE_REAL_LIDAR_DRIVING,
                "the lidar, odometry and network parts calibrated again",
                "mixed pixels counted per edge beam off its own surface, the geometry's intervals at least a "
                "cluster-robust sandwich over the beams, the noise again from the scans while driving; "
                "`lidar.noise_at_range` and `lidar.noise_at_range_driving` are the noise at the still spans' median "
                "range from the still spans and from the scans while driving",
            ),
            *_again(
                COVERAGE_REAL_LIDAR_ROBUST,
                "the same parts again",
                "a beam's mean in a still span taken without its returns more than 5 robust scales off its median, "
                "where one return a metre off had moved every other return's deviation; the beams' spread read per "
                "deviation over the noise at its own range, at the degrees of freedom those means leave and without "
                "returns 5 of the beam's own robust scales off; edge beams that mostly see neither of the map's "
                "surfaces left out of the mixed pixels; other robots masked up to the fitted room's surface",
            ),
            *_again(
                COVERAGE_REAL_LIDAR_ANGLE,
                "the same parts again",
                "the geometry's intervals (mounting offsets, range bias, walls, boxes) widened for the beams' angle "
                "errors, which no still scan identifies: each beam's error, 0.002 rad as its standard deviation (the "
                "datasheets' angular accuracy), carried through the fit and added in quadrature; the still spans' "
                "mean ranges for the geometry without returns far off the beam's median (mixed pixels had moved "
                "them); a beam that a moved box shows another face at a graze left out of the fit; a return on the "
                "other surface of a depth edge no mixed pixel, and the noise's own tail beyond the margin taken out "
                "of the mixed pixels' count as its background",
            ),
        ]
    )


def _again(name: str, how: str, what: str) -> list[str]:
    """A paragraph and its table: the drawn realities' recordings calibrated again (`how`), with `what` changed."""
    run = run_of(RESULTS / name)
    link = f"../benchmarks/results/{name}"
    lead = f"The same recordings, {how} at {run['commit'][:7]} (`{run['command']}`: {what}; "
    return [
        "",
        prose(lead + f"[run.json]({link}/run.json)): " + _coverage_line(name) + ":"),
        "",
        coverage_docs(name).split("\n", 2)[2],
    ]


REAL_BAGS = "real_bags"
"""Public real-robot bags with nothing but scans (benchmarks/real_bag_lidar.py)."""


def real_bags_docs() -> str:
    """docs/lidar.md: what the scans alone of public real-robot bags gave."""
    folder = RESULTS / REAL_BAGS
    run = run_of(folder)
    rows = []
    for block in (folder / "summary.txt").read_text(encoding="utf-8").split("== ")[1:]:
        lines = block.strip().splitlines()
        name = lines[0].strip()
        head = lines[1]
        scans = head.split(": ", 1)[1].split(", range")[0]
        values = {ln.split()[0]: ln for ln in lines[2:] if ln.startswith(("lidar.", "noise at"))}

        at = next((ln for ln in lines if ln.startswith("noise at")), "")
        at_cell = f"{at.split()[2]} m: {float(at.split()[4]) * 1e3:.3g} mm {_mm(at.split()[6:8])}" if at else "-"
        still = next((ln for ln in lines if "still span" in ln), "- none").lstrip("- ").split(" found")[0]
        rows.append(
            f"| {name} | {scans} | {_cell(values, 'lidar.rate_hz')} | {_cell(values, 'lidar.range_step_m')} | "
            f"{values.get('lidar.no_return', '- -').split()[1]} | {still} | {at_cell} |"
        )
    return "\n".join(
        [
            prose(
                f"**Public real-robot bags with nothing but scans** (`{run['command']}` at {run['commit']}, "
                f"[summary.txt](../benchmarks/results/{REAL_BAGS}/summary.txt), which bags: "
                f"[run.json](../benchmarks/results/{REAL_BAGS}/run.json)): no odometry, no map, so what the scans "
                "alone tell (`pipeline/calibration/scan_only.py`). Rate and step with their 95 % intervals; the noise "
                "at the median range of the still spans, where intercept and growth trade off:",
            ),
            "",
            "| bag | scans | rate | range step | no return | still | noise at the median range |",
            "|---|---|---|---|---|---|---|",
            *rows,
        ]
    )


def _cell(values: dict[str, str], key: str) -> str:
    line = values.get(key, "")
    if not line or "unidentifiable" in line:
        return "-"
    parts = line.split()
    return f"{float(parts[1]):.4g} {parts[2]} {' '.join(parts[3:5])}".strip()


def _mm(interval: list[str]) -> str:
    lo, hi = (float(x.strip("[],")) for x in interval)
    return f"[{lo * 1e3:.3g}, {hi * 1e3:.3g}]"


LAYOUT_SETTINGS = (
    ("five DAgger rounds (`layouts_dagger.yaml` as committed)", "dagger5", (1, 2)),
    ("three rounds, each fit at learning rate 5e-4", "dagger3_lr5e-4", (1, 2)),
    ("three rounds, previous command observed", "memory3", (1, 2)),
    ("five rounds, previous command observed (`layouts_memory.yaml`)", "memory5", (1, 2)),
    ("the same, previous command hidden in half the fit's samples", "memory5_dropout", (1, 2)),
    ("hidden in a quarter (`layouts_memory_dropout.yaml` as committed)", "memory5_dropout25", (1, 2, 3, 4)),
)


def _recounted(folder: Path) -> dict[str, Any]:
    rows = json.loads((RESULTS / "recount.json").read_text(encoding="utf-8"))["rows"]
    wanted = str(folder.relative_to(ROOT))
    return next(r for r in rows if r["folder"] == wanted)


def _timing(summary: Path) -> str:
    found = dict(re.findall(r"(jitter_p99_ms|skew_p99_ms)=([0-9.]+)", summary.read_text(encoding="utf-8")))
    return f"tick jitter p99 {float(found['jitter_p99_ms']):.3g} ms, send skew p99 {float(found['skew_p99_ms']):.3g} ms"


def _twin_recounted(twin: Path, link: str) -> str:
    """A twin run made while aborted episodes were left out: its every-episode rate (recount.json) first."""
    real = read_session_metrics(twin / "metrics.json", "real")
    again = _recounted(twin)
    completed = real.robot_success
    return (
        f"{pct(again['robot_success'])} [{100 * again['robot_success_ci_low']:.1f}, "
        f"{100 * again['robot_success_ci_high']:.1f}], team {pct(again['team_success'])} over all "
        f"{real.episodes} ([recount.json](../benchmarks/results/recount.json)); completed only "
        f"{pct(completed.value)} {interval(completed)}, team {pct(real.team_success.value)}, "
        f"{real.aborted_episodes} of {real.episodes} aborted ([twin]({link}/twin/metrics.json))"
    )


def layouts() -> str:
    rows = [
        "| setting | seed | held-out layouts, robot [95 % CI], team | its fixed layout | held-out, randomized "
        "| twin (`lab`) |",
        "|---|---|---|---|---|---|",
    ]
    for label, name, seeds in LAYOUT_SETTINGS:
        for seed in seeds:
            folder = RESULTS / "layouts" / name / f"s{seed}"
            link = f"../benchmarks/results/layouts/{name}/s{seed}"
            held = read_session_metrics(folder / "sim_random" / "metrics.json", "eval")
            fixed = read_session_metrics(folder / "sim_fixed" / "metrics.json", "eval")
            randomized = read_session_metrics(folder / "sim_random_randomized" / "metrics.json", "eval")
            twin = "-"
            if (folder / "twin" / "metrics.json").is_file():
                sim50 = read_session_metrics(folder / "sim50" / "metrics.json", "eval")
                twin = (
                    f"3x, {sim50.episodes} held-out layouts: {_twin_recounted(folder / 'twin', link)}; the simulator "
                    f"on the same {sim50.episodes} layouts {rate_text(sim50)} ([sim50]({link}/sim50/metrics.json)); "
                    f"{_timing(folder / 'twin' / 'summary.txt')} ([summary.txt]({link}/twin/summary.txt))"
                )
            rows.append(
                f"| {label} | [s{seed}]({link}/sim_random/metrics.json) | {rate_text(held)}, team "
                f"{pct(held.team_success.value)} | {rate_text(fixed)}, team {pct(fixed.team_success.value)} | "
                f"{pct(randomized.robot_success.value)} | {twin} |"
            )
    return "\n".join(rows)


def scenarios() -> str:
    pursuit = RESULTS / "pursuit_random" / "imitation_ppo" / "s0"
    plink = "../benchmarks/results/pursuit_random/imitation_ppo/s0"
    held = read_session_metrics(pursuit / "sim_random" / "metrics.json", "eval")
    held_r = read_session_metrics(pursuit / "sim_random_randomized" / "metrics.json", "eval")
    fixed = read_session_metrics(pursuit / "sim_fixed" / "metrics.json", "eval")
    ten_old = RESULTS / "ten" / "dagger" / "s1"
    old = read_session_metrics(ten_old / "sim_random" / "metrics.json", "eval")
    old_r = read_session_metrics(ten_old / "sim_random_randomized" / "metrics.json", "eval")
    again = RESULTS / "ten" / "dagger_every_episode" / "s1"
    logs = again / "logs" / "benchmarks" / "ten_lab_1x"
    new = read_session_metrics(logs / "sim_random" / "metrics.json", "eval")
    new_r = read_session_metrics(logs / "sim_random_randomized" / "metrics.json", "eval")
    twin = read_session_metrics(logs / "twin" / "metrics.json", "real")
    memory = RESULTS / "ten" / "memory5_dropout25" / "s1"
    mem = read_session_metrics(memory / "sim_random" / "metrics.json", "eval")
    mem_r = read_session_metrics(memory / "sim_random_randomized" / "metrics.json", "eval")
    timing = re.search(
        r"tick jitter p99 ([0-9.]+) ms .*send skew p99 ([0-9.]+) ms", (again / "summary.txt").read_text()
    )
    if timing is None:
        raise SystemExit(f"{again / 'summary.txt'}: no 'twin timing' line")

    def team_ci(m: SessionMetrics) -> str:
        return f"{pct(m.team_success.value)} {interval(m.team_success)}"

    collided = "no collision" if old.collision_rate == 0 else f"collision rate {old.collision_rate:.3f}"
    return "\n".join(
        [
            "| scenario, setting | result files | simulator, robot [95 % CI], team | simulator, randomized "
            "| twin (`lab`) |",
            "|---|---|---|---|---|",
            f"| `pursuit_random`, {held.episodes} held-out layouts; imitation of the go-to-goal controller, then PPO, "
            f"seed 0 | [sim_random]({plink}/sim_random/metrics.json) | robot {rate_text(held)}, team (capture, no "
            f"robot collided) {team_ci(held)}; collision rate {held.collision_rate:.3f} | robot "
            f"{pct(held_r.robot_success.value)}, team {team_ci(held_r)} | - |",
            f"| the same policy on the fixed `pursuit` layout | [sim_fixed]({plink}/sim_fixed/metrics.json) | robot "
            f"{rate_text(fixed)}, team {team_ci(fixed)}; collision rate {fixed.collision_rate:.3f} | - | - |",
            f"| `ten`, `ten_dagger.yaml`, seed 1, {old.episodes} sim episodes | "
            "[dagger/s1](../benchmarks/results/ten/dagger/s1/sim_random/metrics.json) | "
            f"{rate_text(old)}, team {pct(old.team_success.value)}, {collided}, mean time to goal "
            f"{old.mean_time_to_goal_s:.1f} s | {rate_text(old_r)} | 1x, "
            f"{_twin_recounted(ten_old / 'twin', '../benchmarks/results/ten/dagger/s1')}; "
            f"{_timing(ten_old / 'twin' / 'summary.txt')} "
            "([summary.txt](../benchmarks/results/ten/dagger/s1/twin/summary.txt)) |",
            f"| `ten`, `ten_dagger.yaml` trained again, seed 1, {new.episodes} sim episodes, every twin episode "
            "counted | [run.json](../benchmarks/results/ten/dagger_every_episode/s1/run.json) | "
            f"{rate_text(new)}, team {pct(new.team_success.value)} | {rate_text(new_r)} | 1x: {rate_text(twin)}, "
            f"team {pct(twin.team_success.value)}, {twin.aborted_episodes} of {twin.episodes} aborted; tick jitter "
            f"p99 {timing.group(1)} ms, send skew p99 {timing.group(2)} ms "
            "([summary.txt](../benchmarks/results/ten/dagger_every_episode/s1/summary.txt)) |",
            "| `ten`, five rounds with the previous command hidden in a quarter of the samples (`ten_dagger.yaml` "
            "with `world.observation: rich_memory`, `train.imitation: {rounds: 5, epochs: 16, memory_dropout: "
            f"0.25}}`), seed 1, {mem.episodes} sim episodes | "
            "[memory5_dropout25/s1](../benchmarks/results/ten/memory5_dropout25/s1/sim_random/metrics.json) | "
            f"{rate_text(mem)}, team {pct(mem.team_success.value)} | {rate_text(mem_r)} | - |",
        ]
    )


def peers() -> str:
    folder = RESULTS / "peer_interop"
    run = run_of(folder)
    lines = [
        f"Measured with `{run['command']}` at {run['commit']} "
        "([run.json](../benchmarks/results/peer_interop/run.json)):",
        "",
        "| peer | episodes | commands lost | emitter tick jitter p99 | send skew p99 | command delay p50 / p99 | "
        "command -> odometry p50 / p99 |",
        "|---|---|---|---|---|---|---|",
    ]
    for name, label in (
        ("roscpp", "roscpp 1.15 (rospy runner, rosmaster)"),
        ("fastdds", "Fast DDS 2.9 (Cyclone runner)"),
        ("rclpy", "rclpy nodes, Jazzy wheels (Cyclone runner)"),
        ("rclpy_rclpy", "rclpy nodes, Jazzy wheels (rclpy runner)"),
    ):
        f = last_figures((folder / f"{name}.txt").read_text(encoding="utf-8"))
        lines.append(
            f"| {label} | {f['episodes']} | {f['lost']} | {f['jitter_p99_ms']} ms | {f['skew_p99_ms']} ms | "
            f"{f['delay_p50_ms']} / {f['delay_p99_ms']} ms | {f['rtt_p50_ms']} / {f['rtt_p99_ms']} ms |"
        )
    return "\n".join(lines)


def speedup() -> str:
    folder = RESULTS / "sweep_speedup"
    run = run_of(folder)
    f = last_figures((folder / "summary.txt").read_text(encoding="utf-8"))
    return prose(
        f"Measured with `{run['command']}` at {run['commit']} "
        "([run.json](../benchmarks/results/sweep_speedup/run.json)): "
        f"{f['trials']} trials of {f['steps_per_trial']} steps took {f['wall_1']} s on one local worker, "
        f"{f['wall_2']} s on two (speed-up {f['speedup']}) and {f['wall_cluster']} s on a head and a worker node "
        f"with a CPU each (speed-up {f['cluster_speedup']}; both nodes on this machine's two cores)."
    )


SWEEPS = (
    "paper",
    "sac_nstep",
    "share",
    "dqn_nstep",
    "dqn_nstep_converge",
    "shared",
    "centralized_100k",
    "ppo",
    "centralized_300k",
)
"""The committed sweeps in the sweeps table of docs/results.md, in its order (benchmarks/results/sweeps/<name>/)."""
MODE_WORDS = {
    "share": "{mode}, experience shared",
    "dqn_nstep": "{mode}, experience shared, 3-step transitions",
    "sac_nstep": "{mode}, 3-step transitions",
    "dqn_nstep_converge": "{mode}, 3-step transitions",
    "centralized_300k": "{mode}, 300 000 steps",
}
"""How the sweeps table names the mode of a sweep whose settings change it (`share`: `train.share_experience`, one
network per robot with every robot's transitions in every network's replay; `centralized_300k`: three times the
budget; `dqn_nstep`: `share` with `train.n_step: 3`; `sac_nstep`: `paper` with it; `dqn_nstep_converge`: `paper`'s DQN
with it, its stop on a perfect evaluation waiting for convergence)."""


def _sweep_rows(folder: Path) -> Any:
    import polars as pl

    rows = [json.loads(p.read_text(encoding="utf-8")) for p in sorted(folder.glob("trials/*/row.json"))]
    return pl.DataFrame(rows, infer_schema_length=None) if rows else None


def _settings_file(command: str, record: Path) -> str:
    """The settings file a sweep's command names (`--settings PATH`)."""
    words = command.split()
    if "--settings" not in words or words.index("--settings") + 1 >= len(words):
        raise SystemExit(f"{record}: the first run's command names no --settings file: {command!r}")
    return words[words.index("--settings") + 1]


def sweeps() -> str:
    """The committed sweeps' cells: robot success IQM with its interval, convergence in time, the target."""
    from pipeline.bench.stats import TARGET_EPISODES, cell_stats, interval_text

    lines = [
        prose(
            "**The paper's cells, swept on Ray** (100 000 world steps per trial unless the mode says otherwise; each "
            "sweep's settings that differ from params.yaml are the file in its row, `paper.yaml` the paper's; rows, "
            "curves and full tables in [benchmarks/results/sweeps/](benchmarks.md#sweep-results), what each "
            "change does in [docs/experiments/sweeps.md](experiments/sweeps.md)):"
        ),
        "",
        f"| sweep | settings | algorithm | mode | room | seeds | robot success IQM, % [95 % CI] | converged (within "
        f"{TARGET_EPISODES} episodes) | target |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    made: list[str] = []
    commands: dict[str, str] = {}
    machines: set[str] = set()
    for name in SWEEPS:
        folder = RESULTS / "sweeps" / name
        rows = _sweep_rows(folder)
        if rows is None:
            continue
        record = folder / "sweep.json"
        if not record.is_file():
            raise SystemExit(f"{record}: missing: a committed sweep's rows need the record of the runs that made them")
        runs = json.loads(record.read_text(encoding="utf-8"))
        commands[name] = runs[0]["command"]
        settings = _settings_file(runs[0]["command"], record)
        for s in cell_stats(rows):
            lines.append(
                f"| [{name}](../benchmarks/results/sweeps/{name}/results.md) | "
                f"[{Path(settings).name}](../{settings}) | {s.algorithm} | "
                f"{MODE_WORDS.get(name, '{mode}').format(mode=s.mode)} | {s.scenario} | "
                f"{s.seeds} | {100 * s.robot_iqm:.1f} {interval_text(s.robot_ci, s.seeds)} | "
                f"{s.converged_seeds} of {s.seeds} ({s.converged_in_time}) | {'met' if s.meets_target else 'missed'} |"
            )
        commits = sorted({run["commit"][:7] + run["commit"][40:] for run in runs})  # "+local changes" kept
        machines.update(run["machine"] for run in runs)
        made.append(f"{name} at {', '.join(commits)}")
    return (
        "\n".join(lines)
        + "\n\n"
        + _centralized_budget_line()
        + prose(
            "The target: a robot success IQM of at least 95 % over at least 5 seeds, at least 4 in 5 of them converged "
            f"within {TARGET_EPISODES} training episodes (every robot over 80 % in 20 consecutive episodes); 200 "
            "evaluation episodes per seed from the exact starts, every episode counted. Each folder's sweep.json "
            "names every run's command, commit, machine and dates; the paper's: `",
            commands[SWEEPS[0]],
            "`. Made: ",
            "; ".join(made),
            f", on {'; '.join(sorted(machines))}.",
        )
    )


def _centralized_budget_line() -> str:
    """Centralized PPO at three times the budget against shared PPO at the budget (the same gradient steps per robot
    decision), from the committed rows; empty where either sweep is missing."""
    from pipeline.bench.stats import cell_stats

    def cell(name: str, mode: str) -> tuple[Any, Any]:
        rows = _sweep_rows(RESULTS / "sweeps" / name)
        found = [] if rows is None else [c for c in cell_stats(rows) if c.algorithm == "ppo" and c.mode == mode]
        return (found[0], rows.filter(rows["mode"] == mode)) if found else (None, None)

    (central, rows), (shared, _) = cell("centralized_300k", "centralized"), cell("ppo", "shared")
    if central is None or shared is None:
        return ""

    def pct(c: Any) -> str:
        return (
            f"{100 * c.robot_iqm:.1f} % [{100 * c.robot_ci[0]:.1f}, {100 * c.robot_ci[1]:.1f}], team "
            f"{100 * c.team_iqm:.1f} % [{100 * c.team_ci[0]:.1f}, {100 * c.team_ci[1]:.1f}]"
        )

    teams = sorted(100 * float(t) for t in rows["team_success"])
    return (
        prose(
            f"**Centralized mode, measured:** at 300 000 world steps, where its one learner has had shared mode's "
            f"gradient steps per robot decision at 100 000, centralized PPO reaches a robot success IQM of "
            f"{pct(central)} ({central.seeds} seeds), shared PPO at 100 000 {pct(shared)} ({shared.seeds} seeds): "
            "the accounting's factor of three covers the robots' gap. Its seeds split on the team: "
            + ", ".join(f"{t:.1f}" for t in teams)
            + " % of the episodes with all three robots at their goals (a summed reward lets a learner settle for "
            "two robots). [docs/experiments/sweeps.md](experiments/sweeps.md#what-centralized-mode-is)."
        )
        + "\n\n"
    )


def centralized() -> str:
    """What each mode's learner gets from the sweeps' budget (benchmarks/centralized_budget.py's committed table)."""
    folder = RESULTS / "centralized_budget"
    run = run_of(folder)
    text = (folder / "summary.txt").read_text(encoding="utf-8")
    f = last_figures(text)
    lines = [
        "| algorithm | mode | learners | input | outputs | parameters | transitions per learner | gradient steps per "
        "learner | gradient steps per robot decision |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for row in text.splitlines()[1:]:
        cells = row.split()
        if len(cells) != 9 or cells[0] not in ("sac", "dqn", "ppo"):
            continue
        lines.append("| " + " | ".join(cells) + " |")
    budget = int(f["budget"])
    return (
        "\n".join(lines)
        + "\n\n"
        + prose(
            f"Counted by `{run['command']}` at {run['commit']} "
            "([summary](../../benchmarks/results/centralized_budget/summary.txt)) per "
            f"{budget // 1000}k world steps of the paper settings: the centralized learner sees a third of the "
            "transitions and takes a third of the gradient steps per robot decision, over a three times wider input; "
            f"centralized DQN chooses among {f['dqn_joint_actions']} joint actions. It gets shared mode's gradient "
            f"steps per robot decision at {int(f['sac_centralized_needs_at_least']) // 1000}k world steps (SAC, DQN "
            "and PPO alike): a lower bound on the budget it needs, not a measured one.",
        )
    )


def train_speed(folder: Path, summaries: tuple[str, ...], what: str) -> str:
    """The learners' rate against the worlds' own and the updates-only bound, from `folder`'s summaries (one
    `train_speed.py` run each) and its run.json (`what`: how the machine was used)."""
    run = run_of(folder)
    rows, limits, links = [], [], []
    for name in summaries:
        text = (folder / name).read_text(encoding="utf-8")
        links.append(f"[{name}](../benchmarks/results/{folder.name}/{name})")
        for line in text.splitlines():
            cells = line.split()
            if len(cells) > 8 and "/" in cells[0] and cells[0][0] in "sdp" and cells[1].isdigit():
                label = cells[0].replace("[batched]", "")
                bound = line.split("updates-only bound ")[1].split()[0]
                share = line.split("(rate ")[1].split()[0]
                rows.append(f"| {label} | {cells[1]} | {cells[3]} | {cells[7]} | {bound} | {share} |")
        limit = re.search(r"env_only=(\d+)", text.strip().splitlines()[-1])
        limits.append(limit.group(1) if limit else "?")
    commands = run["command"] if isinstance(run["command"], str) else "` and `".join(run["command"])
    return "\n".join(
        [
            prose(
                f"Measured with `{commands}` at {run['commit']} ({', '.join(links)}; {what}): the worlds alone step "
                f"{' and '.join(limits)} steps/s.",
            ),
            "",
            "| algorithm/mode | steps/s | of the worlds' rate | time in gradient updates | updates-only bound, "
            "steps/s | rate / bound |",
            "|---|---|---|---|---|---|",
            *rows,
        ]
    )


BLOCKS: dict[str, Callable[[], str]] = {
    "loop-lab": loop_lab,
    "sim2real": sim2real,
    "ten": ten,
    "recount": recount,
    "busy-host": busy_host,
    "scale": scale,
    "coverage": coverage,
    "coverage-docs": partial(coverage_docs, COVERAGE),
    "coverage-excitation-docs": partial(coverage_docs, COVERAGE_EXCITATION),
    "coverage-rescored-docs": partial(coverage_docs, COVERAGE_RESCORED),
    "coverage-excitation-rescored-docs": partial(coverage_docs, COVERAGE_EXCITATION_RESCORED),
    "coverage-excitation-fine-docs": partial(coverage_docs, COVERAGE_EXCITATION_FINE),
    "coverage-excitation-fine-rescored-docs": partial(coverage_docs, COVERAGE_EXCITATION_FINE_RESCORED),
    "coverage-excitation-fine-arc-docs": partial(coverage_docs, COVERAGE_EXCITATION_FINE_ARC),
    "coverage-excitation-fine-refined-docs": partial(coverage_docs, COVERAGE_EXCITATION_FINE_REFINED),
    "coverage-excitation-fine-more-docs": partial(coverage_docs, COVERAGE_EXCITATION_FINE_MORE),
    "coverage-excitation-fine-40-docs": partial(coverage_docs, COVERAGE_EXCITATION_FINE_40),
    "coverage-policy-20-docs": partial(coverage_docs, COVERAGE_POLICY_20),
    "lidar": lidar_docs,
    "coverage-loop-lab-docs": partial(coverage_docs, COVERAGE_LOOP_LAB),
    "coverage-loop-lab-rescored-docs": partial(coverage_docs, COVERAGE_LOOP_LAB_RESCORED),
    "real-bags": real_bags_docs,
    "layouts": layouts,
    "scenarios": scenarios,
    "peers": peers,
    "speedup": speedup,
    "sweeps": sweeps,
    "centralized": centralized,
    "train-speed": partial(train_speed, RESULTS / "train_speed", ("summary.txt",), "beside a sweep at low priority"),
    "train-speed-met": partial(
        train_speed,
        RESULTS / "train_speed_met",
        ("summary_sac.txt", "summary_dqn.txt"),
        "SAC with nothing else running, DQN beside 15 s of report generation at low priority",
    ),
}
FILES = (
    ROOT / "README.md",
    ROOT / "docs" / "results.md",
    ROOT / "docs" / "world.md",
    ROOT / "docs" / "calibration.md",
    ROOT / "docs" / "lidar.md",
    ROOT / "docs" / "deployment.md",
    ROOT / "docs" / "benchmarks.md",
    ROOT / "docs" / "experiments" / "sweeps.md",
    ROOT / "docs" / "experiments" / "calibration-coverage.md",
)


DOCS_LINK = re.compile(r"\]\((?!https?:|#|/)")
"""The start of a relative link in a block's text."""


def rebased(body: str, where: str) -> str:
    """A ``-docs`` block's text (its links relative to docs/) for the page `where`: one folder further down for a
    page in a folder under docs/ (``docs/experiments/``)."""
    page = Path(where).resolve()
    docs = (ROOT / "docs").resolve()
    if page.parent == docs or docs not in page.parents:
        return body
    up = "../" * (len(page.relative_to(docs).parts) - 1)
    return DOCS_LINK.sub(lambda m: m.group(0) + up, body)


def regenerate(text: str, where: str) -> tuple[str, list[str]]:
    """`text` with every results block rewritten; the names of the blocks that changed. A ``-docs`` block's links
    are relative to docs/, rebased for a page further down (:func:`rebased`)."""
    changed: list[str] = []
    names = [m.group("name") for m in BLOCK.finditer(text)]
    unknown = sorted(set(names) - set(BLOCKS))
    if unknown:
        raise SystemExit(f"{where}: results block(s) {unknown} have no generator; known: {sorted(BLOCKS)}")

    def fill(match: re.Match[str]) -> str:
        name = match.group("name")
        body = BLOCKS[name]() + "\n"
        if name.endswith("-docs"):
            body = rebased(body, where)
        if body != match.group("body"):
            changed.append(match.group("name"))
        return match.group(1) + body + match.group(4)

    return BLOCK.sub(fill, text), changed


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--check", action="store_true", help="only compare; exit 1 naming the blocks that differ")
    args = parser.parse_args(argv)
    stale = []
    for path in FILES:
        text = path.read_text(encoding="utf-8")
        new, changed = regenerate(text, str(path))
        stale += [f"{path.relative_to(ROOT)}: {name}" for name in changed]
        if changed and not args.check:
            path.write_text(new, encoding="utf-8")
    for line in stale:
        print(f"{'differs from its result files' if args.check else 'rewritten'}: {line}")
    return 1 if (stale and args.check) else 0


if __name__ == "__main__":
    sys.exit(main())
