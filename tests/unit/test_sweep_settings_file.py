"""A sweep's settings file: the same trials and settings as the command line's --set and --set-for, and every key
that is not allowed named with the file before anything runs."""

from __future__ import annotations

from pathlib import Path

import pytest

from pipeline.bench.trials import (
    base_mapping,
    expand,
    parse_setting,
    read_settings_file,
    scoped_keys,
    scoped_settings,
    with_settings,
)
from pipeline.errors import ConfigError
from pipeline.params import load_params

ROOT = Path(__file__).resolve().parents[2]
PAPER = ROOT / "benchmarks" / "sweeps" / "paper.yaml"


def test_the_paper_settings_file_equals_its_command_line():
    base = base_mapping(load_params(ROOT / "params.yaml"))
    trials = expand(["sac", "dqn"], ["independent"], ["empty", "obstacles"], [0, 1])
    every, scoped = read_settings_file(PAPER)
    from_file = scoped_keys(trials, scoped)
    flags = ["train.total_steps=100000", "train.selection.every_steps=10000", "train.selection.stop_at_success=1.0"]
    per_algorithm = [
        ["sac", "world.actions.reverse=false"],
        ["sac", "train.updates_per_transition=1.0"],
        ["sac", "train.sac.ent_coef_init=0.05"],
        ["sac", "train.learning_rate_schedule=constant"],
        ["dqn", "train.updates_per_transition=1.0"],
    ]
    from_flags = scoped_settings(trials, per_algorithm)
    base_file = with_settings(base, every)
    base_flags = with_settings(base, [parse_setting(f) for f in flags])
    assert [t.digest(base_file) for t in from_file] == [t.digest(base_flags) for t in from_flags]
    assert [t.name for t in from_file] == [t.name for t in from_flags]


@pytest.mark.parametrize(
    ("text", "needles"),
    [
        ("sac: {train.updates_per_transition: 1.0}\nrainbow: {train.seed: 1}\n", ["rainbow", "all | sac | dqn | ppo"]),
        ("all: {total_steps: 5}\n", ["all.total_steps", "a dotted params.yaml key"]),
        ("dqn: [train.seed]\n", ["dqn", "a mapping of dotted params.yaml keys"]),
        ("- all\n", ["a mapping of all, sac, dqn, ppo"]),
        ("all: {train.total_steps: [unclosed\n", ["valid YAML"]),
    ],
)
def test_a_settings_file_with_keys_not_allowed_names_them(tmp_path, text, needles):
    path = tmp_path / "sweep.yaml"
    path.write_text(text)
    with pytest.raises(ConfigError) as err:
        read_settings_file(path)
    message = str(err.value)
    assert str(path) in message and all(n in message for n in needles), message


def test_an_unknown_params_key_in_the_file_is_refused_with_the_trials_rules(tmp_path):
    path = tmp_path / "sweep.yaml"
    path.write_text("all: {train.totl_steps: 5}\n")
    every, _ = read_settings_file(path)
    base = base_mapping(load_params(ROOT / "params.yaml"))
    with pytest.raises(ConfigError, match="totl_steps"):
        with_settings(base, every)


def test_rows_of_other_settings_are_set_aside_and_named_never_mixed_in(tmp_path):
    from pipeline.bench.sweep import collect, set_aside_stale_rows, trial_folder
    from pipeline.bench.trials import write_row

    base = base_mapping(load_params(ROOT / "params.yaml"))
    current, stale = expand(["sac"], ["independent"], ["empty"], [0, 1])
    for trial in (current, stale):
        trial_folder(tmp_path, trial).mkdir(parents=True)
    write_row(trial_folder(tmp_path, current), {"name": current.name, "params_digest": current.digest(base)})
    write_row(trial_folder(tmp_path, stale), {"name": stale.name, "params_digest": "0123456789abcdef"})
    assert collect(tmp_path, [current, stale], base)["name"].to_list() == [current.name]
    moved = set_aside_stale_rows(tmp_path, [stale])
    assert moved == [trial_folder(tmp_path, stale) / "row.stale-0123456789abcdef.json"] and moved[0].is_file()
    assert not (trial_folder(tmp_path, stale) / "row.json").exists()
    assert set_aside_stale_rows(tmp_path, [stale]) == []  # nothing left to set aside


def test_a_damaged_record_of_runs_is_refused_by_name_before_anything_runs(tmp_path):
    from pipeline.bench.sweep import SweepError, run_sweep
    from pipeline.bench.trials import base_mapping, expand
    from pipeline.params import load_params

    base = base_mapping(load_params())
    for text, says in (("<<<<<<< HEAD\n[]\n", "not readable as JSON"), ('{"command": "x"}', "must be a list of runs")):
        (tmp_path / "sweep.json").write_text(text)
        with pytest.raises(SweepError, match=f"sweep.json: {says}"):
            run_sweep(expand(["sac"], ["independent"], ["empty"], [0]), base, tmp_path)
        assert not (tmp_path / "trials").exists() and (tmp_path / "sweep.json").read_text() == text


@pytest.mark.parametrize("path", sorted((ROOT / "benchmarks" / "sweeps").glob("*.yaml")), ids=lambda p: p.name)
def test_every_committed_settings_file_gives_valid_params_for_the_algorithms_it_names(path):
    every, scoped = read_settings_file(path)
    base = with_settings(base_mapping(load_params(ROOT / "params.yaml")), every)
    named = sorted({algorithm for algorithm, _, _ in scoped}) or ["ppo"]
    mode = "independent" if any(k == "train.share_experience" for _, k, _ in scoped) else "shared"
    for trial in scoped_keys(expand(named, [mode], ["obstacles"], [0]), scoped):
        params = trial.params(base, str(path))
        for _, key, value in (s for s in scoped if s[0] == trial.algorithm):
            node: object = params
            for part in key.split("."):
                node = getattr(node, part)
            assert node == value, (trial.name, key)
