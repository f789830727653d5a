"""benchmarks/collect_results.py's commit of a run's tree, and the tiny loop's settings (pipeline.bench.tiny_loop)."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest
import yaml
from collect_results import commit_of

from pipeline.bench.tiny_loop import TINY_LOOP, copy_checkout, tiny_params

ROOT = Path(__file__).resolve().parents[2]


def _repo(path: Path) -> str:
    env = ["-c", "user.name=t", "-c", "user.email=t@localhost"]
    subprocess.run(["git", "init", "-q", str(path)], check=True)
    (path / "dvc.lock").write_text("schema: '2.0'\n")
    (path / "params.yaml").write_text("a: 1\n")
    subprocess.run(["git", *env, "-C", str(path), "add", "-A"], check=True)
    subprocess.run(["git", *env, "-C", str(path), "commit", "-qm", "x"], check=True)
    return subprocess.run(["git", "-C", str(path), "rev-parse", "HEAD"], capture_output=True, text=True).stdout.strip()


def test_the_runs_own_dvc_lock_is_not_a_local_change_and_anything_else_is(tmp_path):
    head = _repo(tmp_path)
    assert commit_of(tmp_path) == head
    (tmp_path / "dvc.lock").write_text("schema: '2.0'\nstages: {}\n")  # what dvc repro writes
    assert commit_of(tmp_path) == head
    (tmp_path / "params.yaml").write_text("a: 2\n")
    assert commit_of(tmp_path) == head + "+local changes"


def test_the_tiny_loop_changes_only_its_keys_and_merges_nested_ones():
    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    tiny = tiny_params(params)
    assert tiny["train"]["total_steps"] == TINY_LOOP["train"]["total_steps"]
    assert tiny["train"]["ppo"]["n_steps"] == 32
    assert {k: v for k, v in tiny["train"]["ppo"].items() if k not in TINY_LOOP["train"]["ppo"]} == {
        k: v for k, v in params["train"]["ppo"].items() if k not in TINY_LOOP["train"]["ppo"]
    }
    assert tiny["deploy"]["fleet"] == params["deploy"]["fleet"] and params["train"]["total_steps"] != 1600


def test_a_copied_checkout_holds_the_tracked_files(tmp_path):
    _repo(tmp_path / "src")
    (tmp_path / "src" / "untracked.txt").write_text("x")
    copy_checkout(tmp_path / "src", tmp_path / "dest")
    assert sorted(p.name for p in (tmp_path / "dest").iterdir()) == ["dvc.lock", "params.yaml"]


def test_a_run_folder_outside_any_worktree_is_refused_rather_than_given_no_commit(tmp_path):
    with pytest.raises(SystemExit, match="in no git worktree"):
        commit_of(tmp_path)
