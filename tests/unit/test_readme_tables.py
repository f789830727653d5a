"""The result blocks of README.md and docs/ are what benchmarks/readme_tables.py makes of the committed result files."""

from __future__ import annotations

import importlib.util
import json
import shutil
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


def _tables():
    spec = importlib.util.spec_from_file_location("readme_tables", ROOT / "benchmarks" / "readme_tables.py")
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules["readme_tables"] = module
    spec.loader.exec_module(module)
    return module


def test_every_results_block_of_the_readme_and_docs_agrees_with_its_result_files():
    tables = _tables()
    names = []
    for path in tables.FILES:
        text = path.read_text(encoding="utf-8")
        names += [m.group("name") for m in tables.BLOCK.finditer(text)]
        _, changed = tables.regenerate(text, str(path))
        assert changed == [], f"run python benchmarks/readme_tables.py: {path.name} {changed} differ from their files"
    assert sorted(names) == sorted(tables.BLOCKS), "every generator fills one block, and every block has one"


def test_the_readme_holds_the_headline_block_alone_and_docs_results_is_checked_beside_it():
    tables = _tables()
    assert {ROOT / "README.md", ROOT / "docs" / "results.md"} <= set(tables.FILES)
    readme = [m.group("name") for m in tables.BLOCK.finditer((ROOT / "README.md").read_text(encoding="utf-8"))]
    assert readme == ["loop-lab"], "README.md's results are one headline table; the others go in docs/results.md"


def test_a_changed_result_file_shows_as_a_block_that_differs(tmp_path, monkeypatch):
    tables = _tables()
    results = tmp_path / "results"
    shutil.copytree(ROOT / "benchmarks" / "results", results)
    monkeypatch.setattr(tables, "RESULTS", results)
    metrics = results / "loop" / "lab" / "logs" / "real" / "nominal" / "metrics.json"
    data = json.loads(metrics.read_text())
    data["real/robot_success"] = 0.9
    metrics.write_text(json.dumps(data))
    text = (ROOT / "README.md").read_text(encoding="utf-8")
    new, changed = tables.regenerate(text, "README.md")
    assert changed == ["loop-lab"]
    before = next(line for line in text.splitlines() if line.startswith("| nominal |"))
    row = next(line for line in new.splitlines() if line.startswith("| nominal |"))
    assert row.split(" | ")[2].startswith("90.0 % [") and row.split(" | ")[1] == before.split(" | ")[1]


def test_a_block_without_a_generator_is_refused(tmp_path):
    tables = _tables()
    with pytest.raises(SystemExit, match=r"README\.md: results block\(s\) \['typed-by-hand'\] have no generator"):
        tables.regenerate("<!-- results: typed-by-hand -->\n| 99 % |\n<!-- /results -->\n", "README.md")


def test_a_docs_blocks_links_are_rebased_for_a_page_further_down():
    tables = _tables()
    body = "[run.json](../benchmarks/results/x/run.json), [lidar.md](lidar.md#measured), [web](https://a.b), [up](#h)"
    assert tables.rebased(body, str(ROOT / "docs" / "calibration.md")) == body
    assert tables.rebased(body, str(ROOT / "docs" / "experiments" / "page.md")) == (
        "[run.json](../../benchmarks/results/x/run.json), [lidar.md](../lidar.md#measured), [web](https://a.b), "
        "[up](#h)"
    )
