"""Stages interrupted by Ctrl-C keep what they made: the last checkpoint, a valid recording."""

from __future__ import annotations

import json
import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from pipeline.bench.tiny_loop import tiny_params
from pipeline.learn.checkpoint import load_checkpoint
from pipeline.messages.convert import EVENT_NAMES
from pipeline.record import McapLog
from pipeline.record.results import STAGING
from tests.integration.conftest import write_fleet

ROOT = Path(__file__).resolve().parents[2]
pytestmark = pytest.mark.integration


def params_in(tmp: Path, **sections: dict) -> Path:
    data = tiny_params(yaml.safe_load((ROOT / "params.yaml").read_text()), sections)
    path = tmp / "params.yaml"
    path.write_text(yaml.safe_dump(data, sort_keys=False))
    return path


def start(stage: str, cwd: Path) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [sys.executable, str(ROOT / "stages" / f"{stage}.py")],
        cwd=cwd,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def wait_for(predicate, timeout_s: float = 60.0) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        if time.monotonic() > deadline:
            raise AssertionError("condition not reached in time")
        time.sleep(0.1)


def test_ctrl_c_during_training_keeps_the_last_checkpoint(tmp_path):
    params_in(
        tmp_path,
        world={"max_steps": 30},
        train={
            "total_steps": 10_000_000,
            "n_envs": 2,
            "net_arch": [16, 16],
            "checkpoint_every_episodes": 2,
            "ppo": {"n_steps": 16, "minibatch_size": 32},
        },
    )
    proc = start("train", tmp_path)
    meta = tmp_path / "models" / "nominal" / "checkpoint" / "train.json"
    wait_for(meta.exists)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert "interrupted" in err and "Traceback" not in err
    ckpt = load_checkpoint(meta.parent)
    assert ckpt.record.interrupted is True and ckpt.record.world_steps > 0


def test_ctrl_c_in_a_terminal_reaches_the_world_workers_too_and_training_still_keeps_its_checkpoint(tmp_path):
    # a terminal's Ctrl-C goes to the whole process group: the trainer and the processes stepping its worlds
    params_in(
        tmp_path,
        world={"max_steps": 30},
        train={
            "total_steps": 10_000_000,
            "n_envs": 4,
            "world_workers": 2,
            "net_arch": [16, 16],
            "checkpoint_every_episodes": 2,
            "ppo": {"n_steps": 16, "minibatch_size": 32},
        },
    )
    proc = subprocess.Popen(
        [sys.executable, str(ROOT / "stages" / "train.py")],
        cwd=tmp_path,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        start_new_session=True,
    )
    meta = tmp_path / "models" / "nominal" / "checkpoint" / "train.json"
    wait_for(meta.exists)
    os.killpg(proc.pid, signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert "interrupted" in err and "Traceback" not in err and "KeyboardInterrupt" not in err
    ckpt = load_checkpoint(meta.parent)
    assert ckpt.record.interrupted is True and ckpt.record.world_steps > 0


def test_ctrl_c_during_sim_evaluation_closes_a_valid_recording(tiny_policy, tmp_path):
    (tmp_path / "models" / "nominal").mkdir(parents=True)
    (tmp_path / "models" / "nominal" / "policy").symlink_to(tiny_policy)
    params_in(tmp_path, world={"max_steps": 30}, eval_sim={"episodes": 100_000, "chunk_size_bytes": 4096})
    proc = start("eval_sim", tmp_path)
    out = tmp_path / "logs" / "sim" / "nominal"
    staged = out / STAGING / "session.mcap"
    wait_for(lambda: staged.exists() and staged.stat().st_size > 200_000)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    # the finished episodes are published with their results, the staging folder is gone
    log = McapLog(out / "session.mcap")
    assert not log.salvaged and not (out / STAGING).exists()
    events = [EVENT_NAMES[m.msg.event] for m in log.messages(["/mrl/episode"])]
    assert events.count("end") >= 1 and events[-1] == "abort"
    with (out / "episodes.csv").open() as f:
        assert len({row.split(",")[0] for row in list(f)[1:]}) == events.count("end")


def test_ctrl_c_during_deployment_stops_robots_and_closes_the_recording(tiny_policy, tmp_path):
    (tmp_path / "models" / "nominal").mkdir(parents=True)
    (tmp_path / "models" / "nominal" / "policy").symlink_to(tiny_policy)
    fleet = write_fleet(tmp_path / "fleet.yaml")
    # the fleet file's 2x (time_scale 0), not params.yaml's auto: the signal is timed past the first episode
    params_in(tmp_path, deploy={"fleet": str(fleet), "episodes": 1000, "time_scale": 0.0})
    proc = start("deploy", tmp_path)
    staged = tmp_path / "logs" / "real" / "nominal" / STAGING / "session.mcap"
    mcap = tmp_path / "logs" / "real" / "nominal" / "session.mcap"
    wait_for(lambda: staged.exists() and staged.stat().st_size > 50_000)
    time.sleep(4.0)  # past the first episode (30 steps at 2x)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert "Traceback" not in err
    log = McapLog(mcap)
    assert not log.salvaged
    assert any(EVENT_NAMES[m.msg.event] == "abort" for m in log.messages(["/mrl/episode"]))
    # the last command every robot got was zero velocity
    for ns in ("robot_1", "robot_2", "robot_3"):
        last = list(log.messages([f"/{ns}/cmd_vel"]))[-1].msg
        assert last.linear.x == 0.0 and last.angular.z == 0.0
    assert json.dumps(log.metadata()["session"])


def test_bad_params_and_missing_policy_fail_before_work(tiny_policy, tmp_path):
    params_in(tmp_path, train={"algorithm": "dqn", "mode": "swarm"})
    proc = start("train", tmp_path)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 2 and "Traceback" not in err
    assert "train.mode = 'swarm'" in err
    params_in(tmp_path, train={"algorithm": "dqn"})
    proc = start("train", tmp_path)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 2 and "world.actions.kind = 'continuous': 'discrete' for train.algorithm 'dqn'" in err
    params_in(tmp_path)
    for stage in ("export", "eval_sim", "deploy"):
        proc = start(stage, tmp_path)
        _, err = proc.communicate(timeout=60)
        assert proc.returncode == 2 and "Traceback" not in err, (stage, err)
        assert "missing" in err, (stage, err)
    (tmp_path / "models" / "nominal").mkdir(parents=True, exist_ok=True)
    (tmp_path / "models" / "nominal" / "policy").symlink_to(tiny_policy)
    params_in(tmp_path, world={"max_steps": 30}, eval_sim={"out_dir": "/proc/forbidden"})
    proc = start("eval_sim", tmp_path)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 2 and "Traceback" not in err and "/proc/forbidden" in err, err
    assert not re.search(r"eval_sim:\s+\d+%", err)  # refused before the first episode: no progress bar
