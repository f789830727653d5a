"""Real training with tiny budgets, then export: every algorithm and mode, ONNX against the torch network."""

from __future__ import annotations

import json
import tempfile
from pathlib import Path

import numpy as np
import pytest

from pipeline.bench.tiny_loop import tiny_train_config
from pipeline.errors import ConfigError
from pipeline.learn.checkpoint import load_checkpoint
from pipeline.learn.errors import CheckpointError
from pipeline.learn.export import export_policy
from pipeline.learn.trainer import train
from pipeline.params import TrainConfig, world_config
from pipeline.policy.errors import PolicyError, PolicyMismatch
from pipeline.policy.runtime import PolicyRuntime
from pipeline.sim import make_world
from pipeline.sim.env import MultiRobotSim

pytestmark = pytest.mark.integration


def tiny_config(**overrides: object) -> TrainConfig:
    return tiny_train_config(**overrides)


def world_for(algorithm: str, n_robots: int = 2, max_steps: int = 60):
    kind = "discrete" if algorithm == "dqn" else "continuous"
    return make_world(
        world=world_config(
            {
                "scenario": "obstacles",
                "n_robots": n_robots,
                "observation": "rich",
                "max_steps": max_steps,
                "actions": {"kind": kind},
            }
        )
    )


def golden_from_sim(scenario, world, n: int = 12, seed: int = 3) -> np.ndarray:
    sim = MultiRobotSim(scenario, world)
    rng = np.random.default_rng(seed)
    obs = [sim.reset(seed)]
    for _ in range(n - 1):
        if world.actions.kind == "continuous":
            act = rng.uniform(-1, 1, size=(scenario.n_robots, 2))
        else:
            act = rng.integers(0, world.actions.codec().n_discrete, size=scenario.n_robots)
        obs.append(sim.step(act).obs)
    return np.stack(obs)


CASES = [
    ("sac", "independent"),
    ("sac", "shared"),
    ("sac", "centralized"),
    ("dqn", "independent"),
    ("dqn", "shared"),
    ("dqn", "centralized"),
    ("ppo", "independent"),
    ("ppo", "shared"),
    ("ppo", "centralized"),
]


@pytest.mark.parametrize(("algorithm", "mode"), CASES)
def test_train_then_export_matches_torch(tmp_path: Path, algorithm: str, mode: str) -> None:
    scenario, world = world_for(algorithm)
    cfg = tiny_config(algorithm=algorithm, mode=mode)
    result = train(scenario, world, cfg, tmp_path / "run", progress=False)
    assert result.world_steps == cfg.total_steps
    assert result.episodes >= 1
    ckpt = load_checkpoint(result.checkpoint)
    n_learners = scenario.n_robots if mode == "independent" else 1
    assert ckpt.record.n_learners == n_learners and len(ckpt.weights) == n_learners
    curve = (tmp_path / "run" / "curve.csv").read_text().splitlines()
    assert len(curve) == result.episodes + 1
    golden = golden_from_sim(scenario, world)
    exported = export_policy(result.checkpoint, tmp_path / "policy", golden, tolerance=1e-5)
    assert exported.golden_samples == len(golden)
    runtime = PolicyRuntime(tmp_path / "policy")
    assert runtime.robots == scenario.robot_names
    actions = runtime.actions(golden[0])
    if algorithm == "dqn":
        assert actions.shape == (scenario.n_robots,) and actions.dtype == np.int64
    else:
        assert actions.shape == (scenario.n_robots, 2) and np.all(np.abs(actions) <= 1.0)
    commands = runtime.commands(golden[0])
    assert commands.shape == (scenario.n_robots, 2)
    runtime.check_fits(scenario.robot_names, world.layout(), world.actions.kind)


@pytest.mark.parametrize("algorithm", ["ppo", "sac"])
def test_training_leaves_nothing_in_the_temporary_directory(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, algorithm: str
) -> None:
    """The training library's default logger makes an empty SB3-<time> folder per run; ours keeps none."""
    temporary = tmp_path / "tmp"
    temporary.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(temporary))
    scenario, world = world_for(algorithm)
    train(scenario, world, tiny_config(algorithm=algorithm, mode="shared"), tmp_path / "run", progress=False)
    assert [p.name for p in temporary.iterdir() if p.name.startswith("SB3-")] == []


def test_same_seed_same_weights_to_the_bit(tmp_path: Path) -> None:
    scenario, world = world_for("sac")
    cfg = tiny_config(algorithm="sac", mode="independent")
    a = train(scenario, world, cfg, tmp_path / "a", progress=False)
    b = train(scenario, world, cfg, tmp_path / "b", progress=False)
    assert a.digest == b.digest
    assert (tmp_path / "a" / "curve.csv").read_bytes() == (tmp_path / "b" / "curve.csv").read_bytes()
    c = train(scenario, world, tiny_config(algorithm="sac", mode="independent", seed=1), tmp_path / "c", progress=False)
    assert c.digest != a.digest


@pytest.mark.parametrize(("algorithm", "share"), [("dqn", True), ("sac", False)])
def test_n_step_transitions_train_to_the_bit_and_differ_from_one_step(tmp_path: Path, algorithm, share) -> None:
    scenario, world = world_for(algorithm)
    cfg = tiny_config(algorithm=algorithm, mode="independent", n_step=3, share_experience=share)
    a = train(scenario, world, cfg, tmp_path / "a", progress=False)
    b = train(scenario, world, cfg, tmp_path / "b", progress=False)
    one = train(scenario, world, tiny_config(algorithm=algorithm, mode="independent", share_experience=share),
                tmp_path / "one", progress=False)  # fmt: skip
    assert a.digest == b.digest != one.digest
    assert json.loads((a.checkpoint / "train.json").read_text())["train"]["n_step"] == 3


@pytest.fixture(scope="module")
def exported(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, object, object]:
    root = tmp_path_factory.mktemp("exported")
    scenario, world = world_for("sac")
    result = train(scenario, world, tiny_config(algorithm="sac", mode="shared"), root / "run", progress=False)
    export_policy(result.checkpoint, root / "policy", golden_from_sim(scenario, world))
    return root, scenario, world


def test_runtime_refuses_a_policy_for_another_fleet(exported) -> None:
    root, scenario, world = exported
    runtime = PolicyRuntime(root / "policy")
    with pytest.raises(PolicyMismatch, match="trained for 2 robot"):
        runtime.check_fits(("robot_1", "robot_2", "robot_3"), world.layout())
    other = world_config({"lidar": {"beams": 30}}, base=world)
    with pytest.raises(PolicyMismatch, match="reads 15 lidar beams, the world gives 30"):
        runtime.check_fits(scenario.robot_names, other.layout())
    with pytest.raises(PolicyMismatch, match="actions are continuous"):
        runtime.check_fits(scenario.robot_names, world.layout(), "discrete")
    with pytest.raises(PolicyMismatch, match="observations have shape"):
        runtime.actions(np.zeros((3, 21), dtype=np.float32))


def test_runtime_refuses_corrupt_or_replaced_files(exported, tmp_path: Path) -> None:
    root, _, _ = exported
    import shutil

    bad = tmp_path / "bad"
    shutil.copytree(root / "policy", bad)
    data = bytearray((bad / "policy.onnx").read_bytes())
    data[len(data) // 2] ^= 0xFF
    (bad / "policy.onnx").write_bytes(bytes(data))
    with pytest.raises(PolicyError, match="sha256"):
        PolicyRuntime(bad)
    shutil.copytree(root / "policy", tmp_path / "golden_off", dirs_exist_ok=True)
    golden = json.loads((tmp_path / "golden_off" / "golden.json").read_text())
    golden["actions"][0][0][0] += 0.5
    (tmp_path / "golden_off" / "golden.json").write_text(json.dumps(golden))
    with pytest.raises(PolicyError, match="golden observation 0"):
        PolicyRuntime(tmp_path / "golden_off")
    (tmp_path / "golden_off" / "policy.json").write_text("{not json")
    with pytest.raises(PolicyError, match="not JSON"):
        PolicyRuntime(tmp_path / "golden_off")
    with pytest.raises(PolicyError, match="missing"):
        PolicyRuntime(tmp_path / "nowhere")


def test_export_refuses_missing_or_corrupt_checkpoints(exported, tmp_path: Path) -> None:
    root, _, _ = exported
    with pytest.raises(CheckpointError, match="missing"):
        export_policy(tmp_path / "none", tmp_path / "out", np.zeros((1, 2, 21)))
    import shutil

    ckpt = tmp_path / "ckpt"
    shutil.copytree(root / "run" / "checkpoint", ckpt)
    (ckpt / "learner_0.pt").write_bytes(b"garbage")
    with pytest.raises(CheckpointError, match=r"learner_0\.pt"):
        export_policy(ckpt, tmp_path / "out", np.zeros((1, 2, 21)))


def test_train_json_is_typed_versioned_and_checked_on_read(exported, tmp_path: Path) -> None:
    """train.json round-trips through its record; an untagged (earlier) file, an unknown key, a mistyped value or
    robots that are not the scenario's are refused, naming the file and the key, before export writes anything."""
    import shutil

    root, scenario, _ = exported
    record = load_checkpoint(root / "run" / "checkpoint").record
    assert record.format == "mrl-train/1" and record.robots == scenario.robot_names and record.n_learners == 1
    assert record.train.algorithm == "sac" and record.world.actions == record.actions
    source = json.loads((root / "run" / "checkpoint" / "train.json").read_text())

    def broken(name: str, change) -> Path:
        folder = tmp_path / name
        shutil.copytree(root / "run" / "checkpoint", folder)
        data = json.loads(json.dumps(source))
        change(data)
        (folder / "train.json").write_text(json.dumps(data))
        return folder

    untagged = broken("untagged", lambda d: d.pop("format"))
    with pytest.raises(CheckpointError, match=r"train\.json.*earlier version.*train the policy again"):
        export_policy(untagged, tmp_path / "out", np.zeros((1, 2, 21)))
    with pytest.raises(ConfigError, match=r"episodez.*unknown key"):
        load_checkpoint(broken("extra", lambda d: d.update(episodez=3)))
    with pytest.raises(ConfigError, match=r"world_steps.*an integer"):
        load_checkpoint(broken("typed", lambda d: d.update(world_steps="many")))
    with pytest.raises(ConfigError, match=r"robots.*the scenario's robots"):
        load_checkpoint(broken("robots", lambda d: d.update(robots=["robot_9", "robot_2"])))
    assert not (tmp_path / "out").exists()


def test_export_clips_unbounded_ppo_means_like_the_training_library(tmp_path: Path) -> None:
    """A PPO mean far outside [-1, 1] is clipped by predict(); the ONNX graph must do the same."""
    import torch

    from pipeline.learn.checkpoint import save_checkpoint

    scenario, world = world_for("ppo")
    result = train(scenario, world, tiny_config(algorithm="ppo", mode="shared"), tmp_path / "run", progress=False)
    ckpt = load_checkpoint(result.checkpoint)
    weights = [{k: (v * 50.0 if k.startswith("action_net") else v) for k, v in w.items()} for w in ckpt.weights]
    save_checkpoint(tmp_path / "big", ckpt.record, weights)
    golden = golden_from_sim(scenario, world)
    export_policy(tmp_path / "big", tmp_path / "policy", golden)
    actions = PolicyRuntime(tmp_path / "policy").actions(golden[3])
    assert np.abs(actions).max() == pytest.approx(1.0)
    assert isinstance(weights[0]["action_net.weight"], torch.Tensor)


def test_a_forward_only_policy_carries_its_action_range_to_the_runtime(tmp_path: Path) -> None:
    scenario, world = world_for("sac")
    world = world_config({"actions": {"kind": "continuous", "reverse": False}}, base=world)
    result = train(scenario, world, tiny_config(algorithm="sac", mode="shared"), tmp_path / "run", progress=False)
    golden = golden_from_sim(scenario, world)
    export_policy(result.checkpoint, tmp_path / "policy", golden, tolerance=1e-5)
    runtime = PolicyRuntime(tmp_path / "policy")
    assert runtime.codec.reverse is False
    actions = np.concatenate([runtime.actions(o) for o in golden])
    commands = np.concatenate([runtime.commands(o) for o in golden])
    np.testing.assert_allclose(commands[:, 0], 0.5 * (actions[:, 0] + 1.0) * 0.4, atol=1e-6)
    assert commands[:, 0].min() >= 0.0


@pytest.mark.parametrize("mode", ["shared", "centralized"])
def test_a_bounds_scaled_ppo_network_exports_with_its_scaling_folded_in(tmp_path: Path, mode: str) -> None:
    """train.observation_scaling: bounds puts (obs - centre) / half range before the first layer; the exported
    network, which has no scaling of its own, computes the same actions, and the same seed gives the same
    weights to the bit."""
    import torch

    from pipeline.policy.networks import SCALE_CENTER, SCALE_HALF_RANGE, action_network

    scenario, world = world_for("ppo")
    cfg = tiny_config(algorithm="ppo", mode=mode, observation_scaling="bounds")
    result = train(scenario, world, cfg, tmp_path / "run", progress=False)
    again = train(scenario, world, cfg, tmp_path / "again", progress=False)
    assert result.digest == again.digest
    (weights,) = load_checkpoint(result.checkpoint).weights
    low, high = world.layout().bounds(
        (scenario.room.x_min_m, scenario.room.x_max_m),
        (scenario.room.y_min_m, scenario.room.y_max_m),
        world.lidar.range_min_m,
        world.lidar.range_max_m,
    )
    copies = scenario.n_robots if mode == "centralized" else 1
    np.testing.assert_allclose(weights[SCALE_CENTER].numpy(), np.tile((low + high) / 2, copies), rtol=1e-6)
    np.testing.assert_allclose(weights[SCALE_HALF_RANGE].numpy(), np.tile((high - low) / 2, copies), rtol=1e-6)

    golden = golden_from_sim(scenario, world)
    export_policy(result.checkpoint, tmp_path / "policy", golden, tolerance=1e-5)  # ONNX against torch
    runtime = PolicyRuntime(tmp_path / "policy")
    obs = golden.reshape(len(golden), -1) if mode == "centralized" else golden.reshape(-1, golden.shape[-1])
    plain = {k: v.numpy() for k, v in weights.items() if k not in (SCALE_CENTER, SCALE_HALF_RANGE)}
    unscaled = action_network("ppo_actor", plain, discrete=False).forward(obs)
    scaled = np.concatenate([runtime.actions(o).reshape(1, -1) for o in golden]).reshape(unscaled.shape)
    assert np.abs(scaled - unscaled).max() > 1e-3  # the scaling is in the exported network
    # ... and it is the scaling torch computes
    policy_input = (torch.as_tensor(obs) - weights[SCALE_CENTER]) / weights[SCALE_HALF_RANGE]
    reference = action_network("ppo_actor", plain, discrete=False).forward(policy_input.numpy())
    np.testing.assert_allclose(scaled, reference, atol=1e-5)


def test_bounds_scaling_is_refused_for_off_policy_algorithms() -> None:
    from pipeline.errors import ConfigError

    with pytest.raises(ConfigError, match=r"observation_scaling.*'none' with algorithm sac"):
        tiny_config(algorithm="sac", observation_scaling="bounds")
