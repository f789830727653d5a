"""Every verb of `mrl` checks its --out before any work: a file in the way, a file among its parents, a place that
cannot be written: one line naming the option and the path, exit 2, no traceback, nothing created."""

from __future__ import annotations

from pathlib import Path

import pytest

from pipeline.mrl import main

VERBS = {
    "episodes": ["episodes", "missing.mcap"],
    "compare": ["compare", "sim.mcap", "real.mcap"],
    "calibrate": ["calibrate", "missing.mcap"],
    "replay": ["replay", "missing.mcap", "--policy", "nowhere"],
    "deploy": ["deploy", "--policy", "nowhere", "--fleet", "twin"],
    "eval": ["eval", "--policy", "nowhere"],
    "sweep": ["sweep", "--seeds", "1"],
}
BAD = ("file", "file/sub", "/proc/mrl-out")


def out_argument(kind: str, tmp_path: Path, table: bool) -> str:
    blocker = tmp_path / "blocker.txt"
    blocker.write_text("a file\n")
    suffix = ".csv" if table else ""
    if kind == "file":
        return str(tmp_path) if table else str(blocker)  # a folder where a table file goes, a file where a folder goes
    if kind == "file/sub":
        return str(blocker / f"sub{suffix}")
    return f"/proc/mrl-out{suffix}"


@pytest.mark.parametrize("bad", BAD)
@pytest.mark.parametrize("verb", sorted(VERBS))
def test_a_bad_out_is_one_line_before_any_work(verb, bad, tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(Path(__file__).resolve().parents[2])
    out = out_argument(bad, tmp_path, table=verb == "episodes")
    code = main([*VERBS[verb], "--out", out])
    err = capsys.readouterr().err
    assert code == 2, err
    assert "Traceback" not in err and f"--out {out}" in err and len(err.strip().splitlines()) == 1, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["blocker.txt"]  # nothing created
