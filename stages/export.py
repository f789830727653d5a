"""dvc stage `export`: the round's checkpoint -> ONNX policy + JSON description + golden set."""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

from pipeline.learn.export import export_policy, golden_observations
from pipeline.learn.trainer import CHECKPOINT_DIR
from pipeline.params import load_params, round_world
from pipeline.sim import make_world
from pipeline.stage import STAGE_TIMES, run_stage, stage_arguments


def main(argv: Sequence[str] | None = None) -> int:
    args = stage_arguments(__doc__ or "", argv)
    params = load_params(args.params)
    scenario, world = make_world(world=round_world(params, args.round, args.params))
    cfg = params.export
    golden = golden_observations(scenario, world, cfg.golden_observations, seed=params.train.seed)
    out = Path(cfg.out_dir) / args.round / "policy"
    result = export_policy(
        Path(params.train.out_dir) / args.round / CHECKPOINT_DIR, out, golden, cfg.tolerance, cfg.opset
    )
    print(
        f"export: {out} (sha256 {result.onnx_sha256[:12]}), ONNX equals torch on {result.golden_samples} "
        f"golden observations (max |diff| {result.max_abs_diff:.2e})"
    )
    return 0


if __name__ == "__main__":
    sys.exit(run_stage("export", main, STAGE_TIMES))
