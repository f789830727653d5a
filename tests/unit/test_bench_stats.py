"""Statistics across seeds (rliable) on rows whose truth is known, the results table and the trials' expansion."""

from __future__ import annotations

import numpy as np
import polars as pl
import pytest
from scipy import stats as sps

from pipeline.bench.stats import cell_stats, markdown_table, performance_profiles, score_matrices
from pipeline.bench.trials import Trial, expand, parse_axis, scoped_settings
from pipeline.errors import ConfigError
from pipeline.params import load_params


def rows_of(cells: dict[str, np.ndarray], team: float = 0.5) -> pl.DataFrame:
    """Sweep rows: per cell a (seeds x 3 robots) array of robot success."""
    records = []
    for cell, success in cells.items():
        algorithm, mode, scenario = cell.split("/")
        for seed, robots in enumerate(success):
            records.append(
                {
                    "name": f"{algorithm}-{mode}-{scenario}-seed{seed}",
                    "cell": cell,
                    "algorithm": algorithm,
                    "mode": mode,
                    "scenario": scenario,
                    "seed": seed,
                    "robot_success": float(robots.mean()),
                    "team_success": team,
                    "converged_at_episode": 150 + 10 * seed if robots.min() > 0.5 else None,
                    "wall_to_convergence_s": 60.0 + seed if robots.min() > 0.5 else None,
                    "train_wall_s": 100.0 + 30 * seed,
                    "train_steps": 100_000 + 1_000 * seed,
                    "env_steps_per_s": 900.0,
                    **{f"success_robot_{k + 1}": float(v) for k, v in enumerate(robots)},
                }
            )
    return pl.DataFrame(records)


def test_the_iqm_is_the_trimmed_mean_of_seeds_by_robots_with_an_interval_around_it():
    rng = np.random.default_rng(1)
    good = np.clip(rng.normal(0.97, 0.02, size=(5, 3)), 0, 1)
    poor = np.clip(rng.normal(0.6, 0.1, size=(5, 3)), 0, 1)
    poor[0, 1] = 0.0  # one seed's robot failing: the IQM leaves it out, the mean does not
    rows = rows_of({"sac/independent/empty": good, "dqn/independent/obstacles": poor})
    stats = {s.cell: s for s in cell_stats(rows, reps=500)}
    for cell, scores in (("sac/independent/empty", good), ("dqn/independent/obstacles", poor)):
        s = stats[cell]
        assert s.seeds == 5
        assert s.robot_iqm == pytest.approx(sps.trim_mean(scores.ravel(), 0.25))
        assert s.robot_ci[0] <= s.robot_iqm <= s.robot_ci[1] and s.robot_ci[1] - s.robot_ci[0] > 0
        assert list(s.per_robot_iqm) == ["robot_1", "robot_2", "robot_3"]
    assert stats["dqn/independent/obstacles"].robot_iqm > poor.mean()
    assert stats["sac/independent/empty"].converged_seeds == 5
    assert stats["sac/independent/empty"].episodes_to_convergence == 170.0  # median of 150..190
    table = markdown_table(list(stats.values()))
    assert "| sac | independent | empty | 5 |" in table and table.count("\n") == 4
    assert "| 102k, 3 min |" in table  # medians over the seeds: 102 000 steps, 160 s
    assert ("met" in table) == stats["sac/independent/empty"].meets_target
    # the target: IQM >= 95 % over >= 5 seeds, >= 4 of 5 converged within 300 episodes
    good_cell = stats["sac/independent/empty"]
    assert good_cell.robot_iqm >= 0.95 and good_cell.converged_in_time == 5 and good_cell.meets_target
    assert "| 5/5 (5 within 300) |" in table
    episode = pl.col("converged_at_episode")  # two seeds converge after 300 episodes: 3 of 5 in time is too few
    late = rows.with_columns(pl.when(pl.col("seed") >= 3).then(episode + 200).otherwise(episode))
    slow = {s.cell: s for s in cell_stats(late, reps=200)}["sac/independent/empty"]
    assert slow.converged_seeds == 5 and slow.converged_in_time == 3 and not slow.meets_target
    one_late = rows.with_columns(pl.when(pl.col("seed") == 4).then(episode + 200).otherwise(episode))
    enough = {s.cell: s for s in cell_stats(one_late, reps=200)}["sac/independent/empty"]
    assert enough.converged_in_time == 4 and enough.meets_target  # 4 of 5 in time is the bar
    few = {s.cell: s for s in cell_stats(rows.filter(pl.col("seed") < 4), reps=200)}["sac/independent/empty"]
    assert few.seeds == 4 and not few.meets_target  # four seeds are too few whatever they score


def test_a_cells_interval_does_not_depend_on_the_other_cells_or_the_rows_order():
    rng = np.random.default_rng(2)
    cells = {
        f"sac/independent/{room}": np.clip(rng.normal(0.8, 0.1, size=(3, 3)), 0, 1) for room in ("empty", "obstacles")
    }
    rows = rows_of(cells)
    together = {s.cell: s for s in cell_stats(rows, reps=300)}
    shuffled = {s.cell: s for s in cell_stats(rows.sample(fraction=1.0, shuffle=True, seed=3), reps=300)}
    alone = cell_stats(rows.filter(pl.col("cell") == "sac/independent/obstacles"), reps=300)[0]
    for cell, s in together.items():
        assert (s.robot_ci, s.team_ci) == (shuffled[cell].robot_ci, shuffled[cell].team_ci)
    assert (alone.robot_ci, alone.team_ci) == (together[alone.cell].robot_ci, together[alone.cell].team_ci)
    # a different seed draws other resamples: the intervals are the bootstrap's, not fixed numbers
    other = {s.cell: s for s in cell_stats(rows, reps=300, seed=1)}
    assert any(other[c].robot_ci != together[c].robot_ci for c in together)


def test_the_95_percent_interval_covers_the_population_iqm():
    """Seeds x robots drawn around 0.8 (a symmetric distribution: its IQM is 0.8). With 5 seeds of 3 robots the
    stratified bootstrap's interval covered 0.8 in 91 of 100 draws when measured (3 seeds: 86, 10 seeds: 93)."""
    rng = np.random.default_rng(2)
    covered = 0
    trials = 100
    for k in range(trials):
        scores = np.clip(rng.normal(0.8, 0.05, size=(5, 3)), 0, 1)
        (s,) = cell_stats(rows_of({"sac/shared/empty": scores}), reps=300, seed=k)
        covered += s.robot_ci[0] <= 0.8 <= s.robot_ci[1]
    assert covered >= 85


def test_performance_profiles_are_the_share_of_scores_above_each_threshold():
    scores = np.array([[0.2, 0.6, 1.0], [0.4, 0.8, 1.0]])
    taus, profiles, bands = performance_profiles(rows_of({"ppo/centralized/empty": scores}), taus=[0.0, 0.5, 0.9])
    assert list(taus) == [0.0, 0.5, 0.9]
    assert profiles["ppo/centralized/empty"] == pytest.approx([1.0, 4 / 6, 2 / 6])
    assert bands["ppo/centralized/empty"].shape == (2, 3)
    robot, team = score_matrices(rows_of({"ppo/centralized/empty": scores}))["ppo/centralized/empty"]
    assert robot.shape == (2, 3) and team.shape == (2, 1)


def test_trials_expand_with_any_params_key_as_an_axis():
    key, values = parse_axis("train.learning_rate=0.0003,0.001")
    assert key == "train.learning_rate" and values == [0.0003, 0.001]
    trials = expand(["sac", "dqn"], ["independent"], ["empty", "obstacles"], [0, 1, 2], [(key, values)])
    assert len(trials) == 2 * 1 * 2 * 2 * 3
    assert len({t.name for t in trials}) == len(trials)
    first = trials[0]
    assert first == Trial("sac", "independent", "empty", 0, (("train.learning_rate", 0.0003),))
    params = first.params(_base())
    assert params.train.learning_rate == 0.0003 and params.train.algorithm == "sac" and params.train.seed == 0
    assert params.world.actions.kind == "continuous" and params.world.scenario == "empty"
    assert trials[3].params(_base()).world.actions.kind == "continuous"
    dqn = next(t for t in trials if t.algorithm == "dqn")
    assert dqn.params(_base()).world.actions.kind == "discrete"
    with pytest.raises(ConfigError, match="algorithm"):
        expand(["a2c"], ["shared"], ["empty"], [0])
    with pytest.raises(ConfigError, match="KEY=V1,V2"):
        parse_axis("learning_rate")
    with pytest.raises(ConfigError, match="learning_rat"):
        Trial("sac", "shared", "empty", 0, (("train.learning_rat", 1.0),)).params(_base())


def test_settings_for_one_algorithm_go_to_its_trials_and_the_table_shows_them():
    trials = scoped_settings(
        expand(["sac", "dqn"], ["independent"], ["empty"], [0, 1]), [["sac", "train.updates_per_transition=1.0"]]
    )
    sac = [t for t in trials if t.algorithm == "sac"]
    dqn = [t for t in trials if t.algorithm == "dqn"]
    assert all(t.keys == (("train.updates_per_transition", 1.0),) for t in sac)
    assert all(t.keys == () for t in dqn)
    assert sac[0].params(_base()).train.updates_per_transition == 1.0
    assert dqn[0].params(_base()).train.updates_per_transition == load_params().train.updates_per_transition
    with pytest.raises(ConfigError, match="--set-for"):
        scoped_settings(trials, [["td3", "train.gamma=0.9"]])
    with pytest.raises(ConfigError, match="KEY=VALUE"):
        scoped_settings(trials, [["sac", "gamma"]])
    rows = rows_of({"sac/independent/empty": np.full((2, 3), 0.9), "dqn/independent/empty": np.full((2, 3), 0.8)})
    rows = rows.with_columns(
        pl.when(pl.col("algorithm") == "sac")
        .then(pl.lit(f"sac/independent/empty/{sac[0].cell.split('/', 3)[3]}"))
        .otherwise(pl.col("cell"))
        .alias("cell")
    )
    table = markdown_table(cell_stats(rows, reps=50))
    assert "| settings |" in table
    assert "| sac | independent | empty | train.updates_per_transition=1.0 | 2 |" in table
    assert "| dqn | independent | empty | - | 2 |" in table


def _base() -> dict:
    from pipeline.bench.trials import base_mapping

    return base_mapping(load_params())


def test_a_row_of_other_settings_is_stale(tmp_path):
    from pipeline.bench.trials import read_row, write_row
    from pipeline.mappings import merge

    trial = Trial("dqn", "independent", "obstacles", 3)
    base = _base()
    longer = merge(base, {"train": {"total_steps": base["train"]["total_steps"] * 2}})
    assert trial.digest(base) == trial.digest(_base()) != trial.digest(longer)
    assert read_row(tmp_path) is None  # not finished
    write_row(tmp_path, {"name": trial.name, "params_digest": trial.digest(base)})
    assert read_row(tmp_path, trial.digest(base)) == {"name": trial.name, "params_digest": trial.digest(base)}
    assert read_row(tmp_path, trial.digest(longer)) is None  # params.yaml changed since: the trial runs again
    assert [p.name for p in tmp_path.iterdir()] == ["row.json"]  # written whole, no temporary left


def test_a_setting_added_later_leaves_trials_finished_before_it_finished():
    """A trial digested before a setting existed keeps its digest while the setting holds the value that
    behaves as before; any other value makes it stale."""
    import copy
    import hashlib
    import json

    from pipeline.bench.trials import DIGEST_KEYS_ADDED
    from pipeline.mappings import merge, to_mapping

    trial = Trial("ppo", "shared", "obstacles", 1)
    base = _base()
    for key, neutral in DIGEST_KEYS_ADDED.items():  # every added setting at the value that behaves as before
        *path, leaf = key.split(".")
        node = base
        for part in path:
            node = node.setdefault(part, {})
        node[leaf] = neutral
    before = to_mapping(trial.params(base))  # the settings as a trial saw them before the added ones existed
    before["train"].pop("world_workers")
    for key in DIGEST_KEYS_ADDED:
        *path, leaf = key.split(".")
        node = before
        for part in path:
            node = node[part]
        del node[leaf]
    before["world"].pop("network")  # a section that did not exist: gone, not empty
    before["world"]["randomize"].pop("network")
    digest_before = hashlib.sha256(json.dumps(before, sort_keys=True, default=str).encode()).hexdigest()[:16]
    assert trial.digest(base) == digest_before
    for changed in (
        {"world": {"observed_pose": "ground_truth"}},
        {"world": {"reward": {"proximity": -0.5}}},
        {"world": {"randomize": {"network": {"loss_prob": [0.0, 0.06]}}}},
    ):
        assert trial.digest(merge(copy.deepcopy(base), changed)) != digest_before


def test_every_setting_is_either_digested_or_added_with_its_former_behaviour():
    from pathlib import Path

    from pipeline.bench.trials import DIGEST_KEYS_ADDED
    from pipeline.mappings import to_mapping

    def leaves(mapping: dict, prefix: str = ""):
        for key, value in mapping.items():
            yield from leaves(value, f"{prefix}{key}.") if isinstance(value, dict) else [f"{prefix}{key}"]

    listed = Path(__file__).parents[1] / "golden" / "digested_settings.txt"
    digested = {line for line in listed.read_text().splitlines() if line and not line.startswith("#")}
    settings = set(leaves(to_mapping(load_params())))
    new = sorted(settings - digested - set(DIGEST_KEYS_ADDED))
    assert not new, f"settings {new} are in neither {listed.name} nor trials.DIGEST_KEYS_ADDED: say which"
    assert set(DIGEST_KEYS_ADDED) <= settings and not digested & set(DIGEST_KEYS_ADDED)


def test_a_cell_of_one_seed_shows_no_interval():
    rows = rows_of({"sac/independent/empty": np.full((1, 3), 0.9), "dqn/independent/empty": np.full((2, 3), 0.8)})
    table = markdown_table(cell_stats(rows, reps=50))
    sac = next(line for line in table.splitlines() if line.startswith("| sac |"))
    dqn = next(line for line in table.splitlines() if line.startswith("| dqn |"))
    assert sac.count("(one seed: no interval)") == 2 and "[" not in sac
    assert "(one seed" not in dqn and dqn.count("[") == 2
