"""The project's own set-up files agree with each other."""

from __future__ import annotations

import re
from pathlib import Path

import yaml

from pipeline.params import Params

ROOT = Path(__file__).resolve().parents[2]


def readme_commands() -> list[str]:
    text = (ROOT / "README.md").read_text()
    return re.findall(r"```bash\n(.+?)\n```", text)[:2]


def test_readme_opens_with_main_job_then_tests_and_ci_runs_the_test_command():
    main_job, tests = readme_commands()
    assert main_job.endswith("dvc repro") and tests.endswith("python -m pytest -n 2")
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


def _pipeline_imports(path: Path) -> set[str]:
    """Absolute pipeline module names imported by the file at `path`."""
    import ast

    names: set[str] = set()
    tree = ast.parse(path.read_text())
    typing_only = {
        id(n)
        for block in ast.walk(tree)
        if isinstance(block, ast.If) and isinstance(block.test, ast.Name) and block.test.id == "TYPE_CHECKING"
        for stmt in block.body
        for n in ast.walk(stmt)
    }
    for node in ast.walk(tree):
        if id(node) in typing_only:
            continue
        if isinstance(node, ast.Import):
            names |= {a.name for a in node.names if a.name.startswith("pipeline")}
        elif isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("pipeline"):
            names.add(node.module)
            names |= {f"{node.module}.{a.name}" for a in node.names}
    return names


def _module_file(name: str) -> Path | None:
    parts = name.split(".")
    for candidate in (ROOT.joinpath(*parts).with_suffix(".py"), ROOT.joinpath(*parts, "__init__.py")):
        if candidate.is_file():
            return candidate
    return None


def stage_sources(script: Path) -> set[Path]:
    """Every pipeline file that `script` imports, directly or through other pipeline modules."""
    seen: set[Path] = set()
    todo = [script]
    while todo:
        path = todo.pop()
        for name in _pipeline_imports(path):
            parts = name.split(".")
            for k in range(1, len(parts) + 1):  # a package's __init__ runs on import of its modules
                found = _module_file(".".join(parts[:k]))
                if found is not None and found not in seen:
                    seen.add(found)
                    todo.append(found)
    return seen


def test_every_stage_depends_on_the_code_it_runs():
    """dvc reruns a stage when a dependency changes: every pipeline file a stage imports must be one."""
    stages = yaml.safe_load((ROOT / "dvc.yaml").read_text())["stages"]
    for name, stage in stages.items():
        body = stage.get("do", stage)
        script = ROOT / body["cmd"].split()[1]
        deps = [d for d in body["deps"] if not d.startswith("$")]
        uncovered = sorted(
            str(p.relative_to(ROOT))
            for p in stage_sources(script)
            if not any(
                str(p.relative_to(ROOT)) == d or str(p.relative_to(ROOT)).startswith(d.rstrip("/") + "/") for d in deps
            )
        )
        assert not uncovered, f"dvc.yaml stage {name} runs {uncovered} but does not depend on them"


def test_the_offline_integration_modules_exist_and_start_no_fleet():
    """A parallel run gives tests/conftest.py's OFFLINE modules a low priority: none may start a twin, a fleet or a
    peer, whose deadlines would then be missed."""
    from tests.conftest import OFFLINE

    for module in sorted(OFFLINE):
        text = (ROOT / module).read_text()
        assert not re.search(r"write_fleet|twin_session|record_twin_session|ros1_master|open_transport", text), module


def test_every_relative_link_of_the_readme_and_docs_names_a_file_and_heading_that_exist():
    """A reader following a link of README.md or docs/ lands on a file (and a heading, where the link names one)."""
    link = re.compile(r"\]\(([^)\s]+)\)")
    pages = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]
    broken = []
    for page in pages:
        for target in link.findall(page.read_text(encoding="utf-8")):
            if target.startswith(("http://", "https://", "mailto:")):
                continue
            path, _, anchor = target.partition("#")
            where = (page.parent / path).resolve() if path else page
            if not where.exists():
                broken.append(f"{page.relative_to(ROOT)}: {target}")
            elif anchor and where.suffix == ".md":
                headings = {
                    re.sub(r"[^\w\- ]", "", h.strip("# ").lower()).replace(" ", "-")
                    for h in where.read_text(encoding="utf-8").splitlines()
                    if h.startswith("#")
                }
                if anchor not in headings:
                    broken.append(f"{page.relative_to(ROOT)}: {target} (no such heading)")
    assert not broken, broken
