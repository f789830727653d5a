"""Settings judged across training seeds: what each setting can be expected to reach.

Each run is the ``--out`` folder of ``benchmarks/scenarios.py`` for one seed's policy, given as
LABEL=FOLDER; runs with the same label are seeds of one setting. For every setting and every world those
folders hold (``sim_random``: held-out random layouts, ``sim_fixed``: the scenario's own layout,
``sim_random_randomized``, ...) it prints each seed's robot success; their mean with its two-sided
Student-t 95 % interval, cut to [0, 100] % (for the setting's expected figure over seeds; with few seeds
it is wide, not overconfident); rliable's IQM over seeds x robots with its stratified bootstrap 95 %
interval (as the sweep reports it; with 3 to 5 seeds that interval covers less than 95 %); the mean team
success and the mean collision rate. With ``--target WORLD=FRACTION`` it says whether the interval lies
above, around or below a target. It writes one PNG: each seed's figure and the mean with its interval,
a panel per world.

    python benchmarks/seed_spread.py --run "ent 0.01=/tmp/b_s0" --run "ent 0.01=/tmp/b_s1" \\
        --run "ent 0=/tmp/c_s0" --target sim_random=0.9 --target sim_fixed=0.95 --out /tmp/seeds.png
"""

from __future__ import annotations

import argparse
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np

from pipeline.bench.stats import iqm_intervals
from pipeline.core.stats import mean_interval
from pipeline.record.errors import RecordError
from pipeline.record.results import read_session_metrics

WORLD_NAMES = {
    "sim_random": "held-out random layouts",
    "sim_fixed": "its fixed layout",
    "sim_random_randomized": "held-out random layouts, randomized",
}


@dataclass(frozen=True)
class Seed:
    folder: Path
    robot: float
    team: float
    collisions: float
    per_robot: tuple[float, ...]


def _world_figures(path: Path) -> Seed:
    try:
        metrics = read_session_metrics(path, "eval")
    except RecordError as exc:
        raise SystemExit(str(exc)) from None
    return Seed(
        path.parent,
        metrics.robot_success.value,
        metrics.team_success.value,
        metrics.collision_rate,
        metrics.robot_success_each,
    )


def read_runs(specs: list[str]) -> dict[str, dict[str, list[Seed]]]:
    """{setting: {world: [one Seed per run]}}, settings and runs in the order given. Every run of a setting
    must hold the same worlds and robots."""
    settings: dict[str, dict[str, list[Seed]]] = {}
    for spec in specs:
        label, sep, folder = spec.rpartition("=")
        if not sep or not label:
            raise SystemExit(f"--run {spec!r}: expected LABEL=FOLDER")
        worlds = {p.parent.name: p for p in sorted(Path(folder).glob("sim_*/metrics.json"))}
        if not worlds:
            raise SystemExit(
                f"--run {spec!r}: {folder} holds no sim_*/metrics.json (the --out of benchmarks/scenarios.py)"
            )
        setting = settings.setdefault(label, {})
        if setting and set(setting) != set(worlds):
            raise SystemExit(
                f"--run {spec!r}: {folder} holds worlds {sorted(worlds)}, the setting's other runs {sorted(setting)}"
            )
        for world, path in worlds.items():
            seed = _world_figures(path)
            runs = setting.setdefault(world, [])
            if runs and len(runs[0].per_robot) != len(seed.per_robot):
                raise SystemExit(
                    f"{path}: {len(seed.per_robot)} robots, the setting's other runs {len(runs[0].per_robot)}"
                )
            runs.append(seed)
    return settings


def _world_order(world: str) -> tuple[int, str]:
    """Known worlds in WORLD_NAMES' order, then the others by name."""
    known = list(WORLD_NAMES)
    return (known.index(world), "") if world in known else (len(known), world)


def _success_interval(values: list[float]) -> tuple[float, float, float]:
    """The seeds' mean success with its t interval, cut to [0, 1] where success lies (coverage unchanged)."""
    mean, low, high = mean_interval(values)
    return mean, (low if math.isnan(low) else max(low, 0.0)), (high if math.isnan(high) else min(high, 1.0))


def _pct(x: float) -> str:
    return "-" if math.isnan(x) else f"{100 * x:.1f}"


def _verdict(low: float, high: float, target: float) -> str:
    if math.isnan(low):
        return f"one seed: no interval to hold against {_pct(target)} %"
    if low >= target:
        return f"above the target {_pct(target)} %"
    if high < target:
        return f"below the target {_pct(target)} %"
    return f"the target {_pct(target)} % lies inside the interval"


def summary_lines(settings: dict[str, dict[str, list[Seed]]], targets: dict[str, float]) -> list[str]:
    lines = []
    for label, worlds in settings.items():
        for world, runs in sorted(worlds.items(), key=lambda item: _world_order(item[0])):
            robot = [s.robot for s in runs]
            mean, low, high = _success_interval(robot)
            team = float(np.mean([s.team for s in runs]))
            hits = float(np.mean([s.collisions for s in runs]))
            ((iqm, (iqm_low, iqm_high)),) = iqm_intervals([np.array([s.per_robot for s in runs])], f"{label}/{world}")
            line = (
                f"{label} | {WORLD_NAMES.get(world, world)}: {len(runs)} seed{'s' if len(runs) > 1 else ''} "
                f"({', '.join(_pct(x) for x in robot)} %); mean {_pct(mean)} % [{_pct(low)}, {_pct(high)}] (t 95 %), "
                f"IQM {_pct(iqm)} % [{_pct(iqm_low)}, {_pct(iqm_high)}] (stratified bootstrap), "
                f"team {_pct(team)} %, collisions {_pct(hits)} %"
            )
            if world in targets:
                line += f"; {_verdict(low, high, targets[world])}"
            lines.append(line)
    return lines


def draw(settings: dict[str, dict[str, list[Seed]]], targets: dict[str, float], out: Path) -> None:
    worlds = sorted({w for s in settings.values() for w in s}, key=_world_order)
    fig, axes = plt.subplots(1, len(worlds), figsize=(4.5 * len(worlds), 4.2), squeeze=False, sharey=True)
    for ax, world in zip(axes[0], worlds, strict=True):
        for k, figures in enumerate(settings.values()):
            runs = figures.get(world, [])
            if not runs:
                continue
            robot = [100 * s.robot for s in runs]
            mean, low, high = (100 * x for x in _success_interval([s.robot for s in runs]))
            jitter = np.linspace(-0.12, 0.12, len(robot)) if len(robot) > 1 else np.zeros(1)
            ax.scatter(k + jitter, robot, color=f"C{k}", alpha=0.6, s=22)
            if not math.isnan(low):
                ax.errorbar(k + 0.3, mean, yerr=[[mean - low], [high - mean]], color=f"C{k}", capsize=4, fmt="o")
            else:
                ax.plot(k + 0.3, mean, "o", color=f"C{k}")
        if world in targets:
            ax.axhline(100 * targets[world], color="grey", linestyle="--", linewidth=1, label="target")
            ax.legend(loc="lower right", fontsize=8)
        ax.set_xticks(range(len(settings)), list(settings), rotation=20, ha="right", fontsize=8)
        ax.set_title(WORLD_NAMES.get(world, world), fontsize=10)
        ax.set_ylim(-2, 102)
        ax.grid(axis="y", alpha=0.3)
    axes[0][0].set_ylabel("robot success (%)")
    fig.suptitle("small dots: one seed each; large dot and bar: the seeds' mean and its t 95 % interval", fontsize=9)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    plt.close(fig)


def _targets(specs: list[str]) -> dict[str, float]:
    out = {}
    for spec in specs:
        world, sep, value = spec.partition("=")
        try:
            fraction = float(value)
        except ValueError:
            fraction = math.nan
        if not sep or not world or not 0 <= fraction <= 1:
            raise SystemExit(f"--target {spec!r}: expected WORLD=FRACTION with FRACTION in [0, 1], e.g. sim_random=0.9")
        out[world] = fraction
    return out


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--run", action="append", required=True, help="LABEL=FOLDER (repeat; one label per setting)")
    parser.add_argument("--target", action="append", default=[], help="WORLD=FRACTION, e.g. sim_random=0.9")
    parser.add_argument("--out", type=Path, required=True, help="the PNG to write")
    args = parser.parse_args(argv)
    targets = _targets(args.target)
    settings = read_runs(args.run)
    unknown = set(targets) - {w for s in settings.values() for w in s}
    if unknown:
        raise SystemExit(f"--target: no run holds world(s) {sorted(unknown)}")
    print("\n".join(summary_lines(settings, targets)))
    draw(settings, targets, args.out)
    print(f"figure: {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
