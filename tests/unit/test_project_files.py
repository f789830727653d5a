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


def test_readme_opens_with_main_job_then_tests_and_ci_runs_the_test_command():
    main_job, tests = readme_commands()
    assert main_job.endswith("dvc repro") and tests.endswith("python -m pytest")
    for command in (main_job, tests):
        # the venv is activated, so the `python` that dvc stages call is the project's
        assert ". .venv/bin/activate" in command
        # the CPU torch wheel goes in before the project, or pip pulls the CUDA build
        assert command.index("pip install torch==2.13.0") < command.index("pip install -e")
    ci = (ROOT / ".ci" / "run").read_text().splitlines()
    assert tests in ci


def test_readme_has_no_unfilled_figures():
    text = (ROOT / "README.md").read_text()
    assert not re.findall(r"\b[A-Z_]*PLACEHOLDER\b|\bTODO\b|\bTBD\b", text)


def test_params_sections_match_config_and_dvc_stages():
    params = yaml.safe_load((ROOT / "params.yaml").read_text())
    assert set(params) == set(Params.__dataclass_fields__)
    stages = yaml.safe_load((ROOT / "dvc.yaml").read_text())["stages"]
    for name, stage in stages.items():
        body = stage.get("do", stage)  # foreach stages keep their definition under `do`
        assert name in params, f"stage {name} has no params section of its own name"
        assert name in body["params"], f"stage {name} does not depend on its params section"
