"""The replay stage's outputs: action agreement per deployment, open-loop divergence per simulator round."""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from pipeline.analysis.replay import Agreement, Divergence, action_agreement, open_loop_divergence
from pipeline.core.scenario import Scenario
from pipeline.params import WorldConfig
from pipeline.policy.protocol import Policy


@dataclass(frozen=True)
class ReplayResult:
    agreement: dict[str, Agreement]
    divergence: dict[str, Divergence]


def run_replay(
    recordings: dict[str, Path],
    policies: dict[str, Policy],
    scenario: Scenario,
    worlds: dict[str, WorldConfig],
    source: str,
    horizon_s: float,
    max_episodes: int,
    tolerance: float,
) -> ReplayResult:
    """Agreement of each round's policy on its own recording; divergence of `source`'s commands in each world."""
    agreement = {label: action_agreement(recordings[label], policies[label], tolerance) for label in recordings}
    divergence = {
        label: open_loop_divergence(recordings[source], scenario, world, horizon_s, max_episodes)
        for label, world in worlds.items()
    }
    return ReplayResult(agreement, divergence)


def write_replay(result: ReplayResult, source: str, out: Path) -> dict[str, float | None]:
    """replay.json (flat metrics), divergence.png and replay.md into `out`; returns the metrics."""
    out.mkdir(parents=True, exist_ok=True)
    metrics: dict[str, float | None] = {}
    for label, a in result.agreement.items():
        metrics[f"replay/{label}/action_agreement"] = a.agreement
        metrics[f"replay/{label}/max_abs_action_diff"] = a.max_abs_diff
        metrics[f"replay/{label}/steps"] = float(a.steps)
    for label, d in result.divergence.items():
        for t in (1.0, 5.0, 10.0):
            value = d.at(t)
            metrics[f"replay/{source}_commands_in_{label}_sim/error_{t:g}s_m"] = None if math.isnan(value) else value
    (out / "replay.json").write_text(json.dumps(metrics, indent=2, sort_keys=True) + "\n", encoding="utf-8")
    fig = Figure(figsize=(7, 4))
    FigureCanvasAgg(fig)
    ax = fig.add_subplot()
    for label, d in result.divergence.items():
        ax.plot(d.times_s, d.mean_error_m, label=f"{label} sim (mean)")
        ax.fill_between(d.times_s, 0, d.p90_error_m, alpha=0.15, label=f"{label} sim (90th percentile)")
    ax.set_xlabel("time since episode start (s)")
    ax.set_ylabel("position error vs recorded ground truth (m)")
    ax.set_title(f"the {source} deployment's commands replayed open loop")
    ax.grid(alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(out / "divergence.png", dpi=110)
    lines = [
        "| deployment | control steps | policy re-run agrees | max abs diff |",
        "|---|---|---|---|",
    ]
    for label, a in result.agreement.items():
        lines.append(f"| {label} | {a.steps} | {100 * a.agreement:.2f} % | {a.max_abs_diff:.2e} |")
    lines += ["", f"Open-loop replay of the {source} deployment's commands (mean position error, m):", ""]
    lines += ["| simulator | 1 s | 5 s | 10 s | episodes |", "|---|---|---|---|---|"]
    for label, d in result.divergence.items():
        lines.append(f"| {label} | {d.at(1.0):.3f} | {d.at(5.0):.3f} | {d.at(10.0):.3f} | {d.episodes} |")
    lines += ["", "![open-loop divergence](divergence.png)", ""]
    (out / "replay.md").write_text("\n".join(lines), encoding="utf-8")
    return metrics
