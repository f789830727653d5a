"""The project's own set-up files agree with each other."""

from __future__ import annotations

import re
from pathlib import Path

import yaml

from pipeline.config import Params

ROOT = Path(__file__).resolve().parents[2]


def readme_commands() -> list[str]:
    text = (ROOT / "README.md").read_text()
    return re.findall(r"```bash\n(.+?)\n```", text)[:2]


def test_ci_runs_exactly_the_readme_commands():
    main_job, tests = readme_commands()
    assert "dvc repro" in main_job and "pytest" in tests
    ci = (ROOT / ".ci" / "run").read_text().splitlines()
    assert main_job in ci and tests in ci


def test_params_sections_match_config_and_dvc_stages():
    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    assert set(params) == set(Params.__dataclass_fields__)
    stages = yaml.safe_load((ROOT / "dvc.yaml").read_text())["stages"]
    for name, stage in stages.items():
        assert name in params, f"stage {name} has no params section of its own name"
        assert name in stage["params"]
