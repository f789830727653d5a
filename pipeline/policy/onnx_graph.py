"""ONNX graphs of exported policies, written node by node from the networks' arrays.

Every graph has one input ``observation`` float32 (n_robots, obs_size), rows in robot order, and
one output ``action``: float32 (n_robots, 2) in [-1, 1] for continuous policies or int64
(n_robots,) indices for discrete ones, i.e. what the action codec decodes. The multi-agent mode
is inside the graph: ``independent`` runs robot i's row through network i, ``shared`` runs every
row through one network, ``centralized`` flattens all rows into one joint observation and splits
the joint action (for discrete actions the joint index's base-k digits, robot_1 first).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

from pipeline.policy.networks import ActionNetwork

INPUT = "observation"
OUTPUT = "action"


class _Graph:
    def __init__(self, opset: int) -> None:
        self.opset = opset
        self.nodes: list[onnx.NodeProto] = []
        self.inits: list[onnx.TensorProto] = []
        self._n = 0

    def name(self, stem: str) -> str:
        self._n += 1
        return f"{stem}_{self._n}"

    def const(self, stem: str, value: np.ndarray) -> str:
        n = self.name(stem)
        self.inits.append(numpy_helper.from_array(np.asarray(value), n))
        return n

    def op(self, op_type: str, inputs: list[str], stem: str, **attrs: Any) -> str:
        out = self.name(stem)
        self.nodes.append(helper.make_node(op_type, inputs, [out], name=out + "_op", **attrs))
        return out

    def dense(self, x: str, w: np.ndarray, b: np.ndarray, stem: str) -> str:
        return self.op("Gemm", [x, self.const(stem + "_w", w), self.const(stem + "_b", b)], stem, transB=1)

    def network(self, x: str, net: ActionNetwork, stem: str) -> str:
        """(batch, in) -> float actions (batch, n) or int64 indices (batch,)."""
        for k, layer in enumerate(net.hidden):
            x = self.dense(x, layer.weight, layer.bias, f"{stem}_l{k}")
            x = self.op("Relu" if net.activation == "relu" else "Tanh", [x], f"{stem}_act{k}")
        y = self.dense(x, net.out.weight, net.out.bias, f"{stem}_out")
        if net.head == "tanh":
            return self.op("Tanh", [y], f"{stem}_tanh")
        if net.head == "clip":
            lo = self.const(stem + "_lo", np.array(-1.0, dtype=np.float32))
            hi = self.const(stem + "_hi", np.array(1.0, dtype=np.float32))
            return self.op("Clip", [y, lo, hi], f"{stem}_clip")
        if net.head == "dueling_argmax":
            assert net.value is not None
            v = self.dense(x, net.value.weight, net.value.bias, f"{stem}_value")
            if self.opset >= 18:
                axes = self.const(stem + "_axes", np.array([1], dtype=np.int64))
                mean = self.op("ReduceMean", [y, axes], f"{stem}_adv_mean", keepdims=1)
            else:
                mean = self.op("ReduceMean", [y], f"{stem}_adv_mean", axes=[1], keepdims=1)
            centred = self.op("Sub", [y, mean], f"{stem}_adv_centred")
            y = self.op("Add", [v, centred], f"{stem}_q")
        return self.op("ArgMax", [y], f"{stem}_argmax", axis=1, keepdims=0)


def policy_graph(
    networks: list[ActionNetwork],
    mode: str,
    n_robots: int,
    obs_size: int,
    discrete: bool,
    n_discrete: int,
    opset: int = 17,
    doc: str = "",
) -> onnx.ModelProto:
    """The ONNX model of a policy: `networks` has one entry per robot (independent) or one (shared, centralized)."""
    g = _Graph(opset)
    if mode == "independent":
        if len(networks) != n_robots:
            raise ValueError(f"independent mode needs {n_robots} networks, got {len(networks)}")
        outs = []
        for i, net in enumerate(networks):
            idx = g.const(f"robot{i}_index", np.array([i], dtype=np.int64))
            row = g.op("Gather", [INPUT, idx], f"robot{i}_obs", axis=0)
            y = g.network(row, net, f"robot{i}")
            outs.append(y)
        result = g.op("Concat", outs, "actions", axis=0)
    elif mode == "shared":
        result = g.network(INPUT, networks[0], "shared")
    elif mode == "centralized":
        flat = g.op(
            "Reshape", [INPUT, g.const("joint_shape", np.array([1, n_robots * obs_size], dtype=np.int64))], "joint"
        )
        y = g.network(flat, networks[0], "central")
        if discrete:
            powers = g.const("powers", (n_discrete ** np.arange(n_robots - 1, -1, -1)).astype(np.int64))
            base = g.const("base", np.array(n_discrete, dtype=np.int64))
            quotient = g.op("Div", [y, powers], "joint_div")
            result = g.op("Mod", [quotient, base], "digits", fmod=0)
        else:
            result = g.op("Reshape", [y, g.const("split_shape", np.array([n_robots, 2], dtype=np.int64))], "split")
    else:
        raise ValueError(f"unknown mode {mode!r}")
    g.nodes.append(helper.make_node("Identity", [result], [OUTPUT], name="output"))
    out_type = TensorProto.INT64 if discrete else TensorProto.FLOAT
    out_shape = [n_robots] if discrete else [n_robots, 2]
    graph = helper.make_graph(
        g.nodes,
        "policy",
        [helper.make_tensor_value_info(INPUT, TensorProto.FLOAT, [n_robots, obs_size])],
        [helper.make_tensor_value_info(OUTPUT, out_type, out_shape)],
        initializer=g.inits,
        doc_string=doc,
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", opset)], producer_name="mrl-export")
    model.ir_version = min(model.ir_version, 9)
    onnx.checker.check_model(model, full_check=True)
    return model
