"""dvc stage `fleet_check`: before any training, the deploy fleet's DDS domain: a pinned one that another deployment
on this machine holds is refused now (exit 3, naming it), not when the deployment starts after the trainings.

Writes ``fleet_check.json`` (the fleet and its pinned domain, or none: a twin then takes a free one): the same content
as long as the fleet file's choice is the same, so the trainings that depend on it run again only when that changes.
"""

from __future__ import annotations

import json
import sys
from collections.abc import Sequence
from pathlib import Path

from pipeline.params import load_params
from pipeline.ros.domains import check_pinned_domain
from pipeline.ros.fleet import load_fleet
from pipeline.stage import STAGE_TIMES, run_stage, stage_arguments


def main(argv: Sequence[str] | None = None) -> int:
    args = stage_arguments(__doc__ or "", argv, rounds=False)
    params = load_params(args.params)
    fleet = load_fleet(params.deploy.fleet)
    pinned = fleet.network.domain_id if fleet.transport != "ros1" else None
    check_pinned_domain(pinned, params.deploy.fleet)
    out = Path(params.fleet_check.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"fleet": params.deploy.fleet, "pinned_domain": pinned}, indent=1) + "\n")
    print(f"fleet_check: {params.deploy.fleet}: " + (f"DDS domain {pinned} is free" if pinned is not None else
          "no pinned domain (a twin takes a free one)"))  # fmt: skip
    return 0


if __name__ == "__main__":
    sys.exit(run_stage("fleet_check", main, STAGE_TIMES))
