"""The params files of the README's measured settings (benchmarks/settings/) stay loadable as params.yaml evolves,
and change from params.yaml only world and training keys, the export folder and the time scale their deployments
ran at."""

from __future__ import annotations

from pathlib import Path

import pytest

from pipeline.mappings import to_mapping
from pipeline.params import load_params

ROOT = Path(__file__).resolve().parents[2]
SETTINGS = sorted((ROOT / "benchmarks" / "settings").glob("*.yaml"))


def _flat(mapping: object, prefix: str = "") -> dict[str, object]:
    if not isinstance(mapping, dict):
        return {prefix: mapping}
    out: dict[str, object] = {}
    for key, value in mapping.items():
        out.update(_flat(value, f"{prefix}.{key}" if prefix else str(key)))
    return out


def test_there_are_settings_files():
    assert "layouts_dagger.yaml" in {p.name for p in SETTINGS}


@pytest.mark.parametrize("path", SETTINGS, ids=lambda p: p.name)
def test_a_settings_file_loads_and_trains_from_the_path_teacher_without_ppo(path):
    params = load_params(path)
    assert params.train.imitation.teacher == "path"
    assert params.train.imitation.rounds > 1
    assert params.train.total_steps == 0
    assert params.world.observed_pose == "ground_truth"
    assert params.train.out_dir == params.export.out_dir != load_params(ROOT / "params.yaml").train.out_dir


@pytest.mark.parametrize("path", SETTINGS, ids=lambda p: p.name)
def test_a_settings_file_differs_from_params_yaml_only_in_training_and_world_keys(path):
    base = _flat(to_mapping(load_params(ROOT / "params.yaml")))
    mine = _flat(to_mapping(load_params(path)))
    changed = {k for k in base if base[k] != mine[k]}
    assert changed, path
    # deploy.time_scale: the scale the setting's deployments were measured at (3x, before the loop's default became
    # auto)
    assert all(k.split(".")[0] in ("world", "train", "export") or k == "deploy.time_scale" for k in changed), changed
    assert {k for k in changed if k.startswith("export.")} == {"export.out_dir"}
