"""benchmarks/seed_spread.py and the statistics under it: settings judged across seeds, with intervals that
cover the truth, a picture, and bad runs refused before anything is written."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from PIL import Image
from scipy import stats as sps
from seed_spread import main

from pipeline.core.stats import mean_interval

ROOT = Path(__file__).resolve().parents[2]


def _seed_folder(folder: Path, worlds: dict[str, tuple[float, float, float]]) -> Path:
    """A benchmarks/scenarios.py --out folder: per world (robot_1, robot_2, robot_3) success."""
    for world, robots in worlds.items():
        (folder / world).mkdir(parents=True)
        metrics = {
            "eval/episodes": 20.0,
            "eval/aborted_episodes": 0.0,
            "eval/robot_success": sum(robots) / 3,
            "eval/team_success": min(robots) / 2,
            "eval/collision_rate": 1 - max(robots),
            **{f"eval/robot_{k + 1}_success": r for k, r in enumerate(robots)},
        }
        (folder / world / "metrics.json").write_text(json.dumps(metrics))
    return folder


def test_the_t_interval_of_a_few_seeds_covers_the_settings_expected_success():
    """Each seed of a setting has a success of its own (seed to seed spread) and is measured on 600
    robot-episodes (binomial noise): the interval over 4 seeds covers the setting's expected success about
    95 % of the time (measured: 0.943 of 1000 draws)."""
    rng = np.random.default_rng(7)
    truth, covered, draws = 0.7, 0, 1000
    for _ in range(draws):
        per_seed = rng.beta(truth * 40, (1 - truth) * 40, size=4)  # mean 0.7, sd 0.07 between seeds
        measured = rng.binomial(600, per_seed) / 600
        _, low, high = mean_interval(measured)
        covered += low <= truth <= high
    assert 0.93 <= covered / draws <= 0.97


def test_the_t_interval_is_the_textbook_one_and_a_single_run_has_none():
    mean, low, high = mean_interval([0.693, 0.615, 0.663, 0.695])
    half = sps.t.ppf(0.975, 3) * np.std([0.693, 0.615, 0.663, 0.695], ddof=1) / 2
    assert mean == pytest.approx(0.6665) and (low, high) == pytest.approx((mean - half, mean + half))
    one = mean_interval([0.5])
    assert one[0] == 0.5 and math.isnan(one[1]) and math.isnan(one[2])
    with pytest.raises(ValueError, match="at least one"):
        mean_interval([])


def test_settings_are_summarised_per_world_and_drawn(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    a = [(0.7, 0.8, 0.9), (0.6, 0.7, 0.8), (0.8, 0.8, 0.8)]
    fixed = [(1.0, 1.0, 1.0), (1.0, 0.0, 0.0), (1.0, 0.0, 0.0)]
    runs = [
        _seed_folder(tmp_path / f"a{k}", {"sim_random": r, "sim_fixed": f})
        for k, (r, f) in enumerate(zip(a, fixed, strict=True))
    ]
    low_run = _seed_folder(tmp_path / "b0", {"sim_random": (0.2, 0.3, 0.4), "sim_fixed": (0.0, 0.0, 0.0)})
    out = tmp_path / "fig" / "seeds.png"
    argv = [*(x for r in runs for x in ("--run", f"ent=0.01={r}")), "--run", f"plain={low_run}"]
    assert main([*argv, "--target", "sim_random=0.9", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    seeds = [sum(r) / 3 for r in a]
    mean, low, high = mean_interval(seeds)
    lines = text.splitlines()
    assert lines[0].startswith("ent=0.01 | held-out random layouts") and lines[1].startswith("ent=0.01 | its fixed")
    held_out = lines[0]
    assert "3 seeds (80.0, 70.0, 80.0 %)" in held_out
    assert f"mean {100 * mean:.1f} % [{100 * low:.1f}, {100 * high:.1f}] (t 95 %)" in held_out
    iqm = sps.trim_mean(np.ravel(a), 0.25)  # rliable's IQM over seeds x robots
    assert f"IQM {100 * iqm:.1f} % [" in held_out
    assert "team 35.0 %, collisions 16.7 %" in held_out  # the seeds' means of team success and collision rate
    # the t interval reaches past 0.9: the target is inside it, not met, not missed
    assert high > 0.9 and "the target 90.0 % lies inside the interval" in held_out
    assert "plain | held-out random layouts: 1 seed (30.0 %); mean 30.0 % [-, -]" in text
    assert "one seed: no interval to hold against 90.0 %" in text
    # the t interval of (100, 33.3, 33.3) % reaches past both ends; success lies in [0, 100] %
    assert "ent=0.01 | its fixed layout: 3 seeds (100.0, 33.3, 33.3 %); mean 55.6 % [0.0, 100.0] (t 95 %)" in text
    with Image.open(out) as picture:
        assert picture.size[0] > 600 and picture.size[1] > 300


def test_bad_runs_and_targets_are_refused_before_the_figure_is_written(tmp_path: Path) -> None:
    out = tmp_path / "seeds.png"
    good = _seed_folder(tmp_path / "g", {"sim_random": (0.5, 0.5, 0.5)})
    with pytest.raises(SystemExit, match="expected LABEL=FOLDER"):
        main(["--run", str(good), "--out", str(out)])
    with pytest.raises(SystemExit, match=r"holds no sim_\*/metrics\.json"):
        main(["--run", f"x={tmp_path / 'nothing'}", "--out", str(out)])
    other = _seed_folder(tmp_path / "o", {"sim_fixed": (0.5, 0.5, 0.5)})
    with pytest.raises(SystemExit, match=r"holds worlds \['sim_fixed'\], the setting's other runs \['sim_random'\]"):
        main(["--run", f"x={good}", "--run", f"x={other}", "--out", str(out)])
    broken = tmp_path / "broken" / "sim_random"
    broken.mkdir(parents=True)
    (broken / "metrics.json").write_text("{not json")
    with pytest.raises(SystemExit, match=r"broken/sim_random/metrics\.json: unreadable or not JSON"):
        main(["--run", f"x={broken.parent}", "--out", str(out)])
    (broken / "metrics.json").write_text(json.dumps({"eval/episodes": 3.0, "eval/aborted_episodes": 3.0}))
    with pytest.raises(
        SystemExit, match=r"metrics\.json: eval/robot_success, eval/team_success, eval/collision_rate missing"
    ):
        main(["--run", f"x={broken.parent}", "--out", str(out)])
    with pytest.raises(SystemExit, match=r"--target 'sim_random=90': expected WORLD=FRACTION"):
        main(["--run", f"x={good}", "--target", "sim_random=90", "--out", str(out)])
    with pytest.raises(SystemExit, match=r"no run holds world\(s\) \['sim_fixd'\]"):
        main(["--run", f"x={good}", "--target", "sim_fixd=0.9", "--out", str(out)])
    assert not out.exists()
