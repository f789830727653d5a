"""The policy runtime: an exported policy (ONNX + JSON) mapping observations to actions for every robot.

It needs onnxruntime and numpy only: no training library, nothing unpickled. Sim evaluation,
deployment and replay all act through it, with the observation layout and action codec it
describes, so the same file gives the same actions everywhere.
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import onnxruntime

from pipeline.core.observation import ObservationLayout
from pipeline.mappings import to_mapping
from pipeline.policy.errors import PolicyError, PolicyMismatch
from pipeline.policy.spec import SPEC_FILE, PolicySpec, read_golden, read_policy_spec

_OUTPUT_KINDS = {"tensor(float)": "continuous", "tensor(int64)": "discrete"}
"""The kind of actions an ONNX policy's output element type carries."""


class PolicyRuntime:
    """A loaded policy (a :class:`~pipeline.policy.protocol.Policy`). `actions(obs)` for obs (n_robots, obs_size)
    float32 in robot order.

    `folder` holds policy.json, policy.onnx and golden.json; loading checks the ONNX file's
    digest and, unless `verify` is False, replays the golden set.
    """

    def __init__(self, folder: str | Path, verify: bool = True) -> None:
        self.folder = Path(folder)
        spec_path = self.folder / SPEC_FILE if self.folder.is_dir() or not self.folder.suffix else self.folder
        if spec_path.name != SPEC_FILE:
            self.folder = spec_path.parent
        self.spec_path = spec_path
        self.spec: PolicySpec = read_policy_spec(spec_path)
        onnx_path = self.folder / self.spec.onnx.file
        try:
            data = onnx_path.read_bytes()
        except OSError as exc:
            raise PolicyError(
                str(onnx_path), f"missing or unreadable ({exc.strerror}); export the policy first"
            ) from exc
        digest = hashlib.sha256(data).hexdigest()
        if digest != self.spec.onnx.sha256:
            raise PolicyError(str(onnx_path), "does not match the sha256 recorded in policy.json (corrupt or replaced)")
        self.digest = digest
        options = onnxruntime.SessionOptions()
        options.intra_op_num_threads = 1
        options.inter_op_num_threads = 1
        try:
            self._session = onnxruntime.InferenceSession(data, options, providers=["CPUExecutionProvider"])
        except Exception as exc:  # onnxruntime raises its own exception types for invalid graphs
            raise PolicyError(str(onnx_path), f"not a loadable ONNX graph ({exc})") from exc
        self._input = self.spec.onnx.input
        self.robots: tuple[str, ...] = self.spec.robots
        self.layout = self.spec.world.layout()
        self.codec = self.spec.world.codec().for_scenario(self.spec.scenario)
        self._check_output_kind(onnx_path)
        if verify:
            self.verify_golden()

    def _check_output_kind(self, onnx_path: Path) -> None:
        """Refuse a policy.json whose world.actions.kind is not the kind of actions its ONNX graph outputs."""
        output = self._session.get_outputs()[0]
        graph_kind = _OUTPUT_KINDS.get(output.type)
        if graph_kind is None:
            raise PolicyError(
                str(onnx_path),
                f"its output {output.name!r} is {output.type}; a policy outputs float (continuous) "
                "or int64 (discrete) actions",
            )
        if graph_kind != self.codec.kind:
            raise PolicyError(
                str(self.spec_path),
                f"world.actions.kind is {self.codec.kind!r} but the policy was trained with {graph_kind!r} "
                f"(its ONNX graph outputs {output.type} actions of shape {output.shape}); "
                "export it again instead of editing world.actions.kind",
            )

    @property
    def n_robots(self) -> int:
        return len(self.robots)

    @property
    def name(self) -> str:
        return f"{self.spec.algorithm}/{self.spec.mode} ({self.digest[:12]})"

    @property
    def document(self) -> dict[str, Any]:
        """The spec as plain data, for the ``policy`` document of a recording."""
        document: dict[str, Any] = to_mapping(self.spec)
        return document

    @property
    def session_extra(self) -> dict[str, str]:
        """Nothing beyond the deployment's own session metadata: the policy itself drives."""
        return {}

    def actions(self, obs: np.ndarray) -> np.ndarray:
        """Policy outputs for the codec: (n_robots, 2) in [-1, 1] or (n_robots,) int64 indices."""
        x = np.asarray(obs, dtype=np.float32)
        if x.shape != (self.n_robots, self.layout.size):
            raise PolicyMismatch(
                self.name,
                [f"observations have shape {x.shape}, the policy takes ({self.n_robots}, {self.layout.size})"],
            )
        return np.asarray(self._session.run(None, {self._input: x})[0])

    def commands(self, obs: np.ndarray) -> np.ndarray:
        """(n_robots, 2) velocity commands (v m/s, w rad/s) decoded and clamped by the policy's codec."""
        return self.codec.decode(self.actions(obs))

    def __call__(self, obs: np.ndarray) -> np.ndarray:
        return self.actions(obs)

    def verify_golden(self) -> int:
        """Re-run the golden set stored with the policy; PolicyError if an action differs. Returns its size."""
        path = self.folder / self.spec.golden
        golden = read_golden(path)
        obs, tol, on_commands = golden.observations, golden.tolerance, golden.compared == "commands"
        expected = golden.actions if self.codec.kind == "continuous" else golden.actions.astype(np.int64)
        want = (len(obs), self.n_robots) + ((2,) if self.codec.kind == "continuous" else ())
        if expected.shape != want:
            raise PolicyError(
                str(path),
                f"actions have shape {expected.shape}; {len(obs)} golden observations of a {self.codec.kind} "
                f"policy for {self.n_robots} robot(s) need {want}",
            )
        for k, o in enumerate(obs):
            got = self.actions(o)
            if self.codec.kind == "discrete":
                if not np.array_equal(got, expected[k]):
                    raise PolicyError(
                        str(path),
                        f"golden observation {k}: the ONNX graph picks actions {got.tolist()}, "
                        f"golden.json has {expected[k].tolist()}",
                    )
                continue
            if on_commands:  # as a share of the robots' limits, after decoding (what reaches a robot)
                if not np.isfinite(got).all():
                    raise PolicyError(str(path), f"golden observation {k}: the ONNX graph's actions are not finite")
                share = self.codec.command_difference(got, expected[k])
                if share > tol:
                    raise PolicyError(
                        str(path),
                        f"golden observation {k}: the ONNX graph's commands differ from golden.json's by {share:.3g} "
                        f"of the robots' limits, beyond its tolerance {tol:g}",
                    )
                continue
            diff = np.nan_to_num(np.abs(got - expected[k]), nan=np.inf)
            if diff.max() > tol:
                robot = int(diff.max(axis=1).argmax())
                raise PolicyError(
                    str(path),
                    f"golden observation {k}: the ONNX graph's actions differ from golden.json's by up to "
                    f"{float(diff.max()):.3g}, beyond its tolerance {tol:g} (robot {self.robots[robot]}: "
                    f"{np.round(got[robot], 6).tolist()} vs {np.round(expected[k][robot], 6).tolist()})",
                )
        return len(obs)

    def check_fits(
        self,
        robots: Sequence[str],
        layout: ObservationLayout,
        action_kind: str | None = None,
        limits: tuple[float, float] | None = None,
    ) -> None:
        """Refuse (PolicyMismatch) a world or fleet whose robots, layout, beam count or actions differ."""
        problems = []
        if tuple(robots) != self.robots:
            problems.append(
                f"it was trained for {self.n_robots} robot(s) {', '.join(self.robots)}, "
                f"the fleet has {len(robots)}: {', '.join(robots)}"
            )
        if layout.name != self.layout.name:
            problems.append(f"observation layout is {self.layout.name!r}, the world uses {layout.name!r}")
        if layout.n_beams != self.layout.n_beams:
            problems.append(f"it reads {self.layout.n_beams} lidar beams, the world gives {layout.n_beams}")
        if action_kind is not None and action_kind != self.codec.kind:
            kind = self.codec.kind
            problems.append(
                f"world.actions.kind is {action_kind!r} but the policy was trained with {kind!r} "
                f"(policy.json world.actions.kind): its actions are {kind}; set world.actions.kind: {kind}, or retrain"
            )
        if limits is not None and (
            limits[0] < self.codec.v_max_mps - 1e-9 or limits[1] < self.codec.w_max_radps - 1e-9
        ):
            problems.append(
                f"it commands up to {self.codec.v_max_mps} m/s and {self.codec.w_max_radps} rad/s, "
                f"beyond the limits {limits[0]} m/s and {limits[1]} rad/s"
            )
        if problems:
            raise PolicyMismatch(self.name, problems)
