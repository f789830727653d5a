"""benchmarks/selection_curves.py: each run's best and last evaluation, the picture, and bad runs refused."""

from __future__ import annotations

from pathlib import Path

import pytest
from PIL import Image
from selection_curves import main

ROOT = Path(__file__).resolve().parents[2]

HEADER = "world_steps,episodes,robot_success,team_success,collision_rate,kept\n"


def _round(folder: Path, rows: list[tuple[int, float, float]]) -> Path:
    folder.mkdir(parents=True)
    lines = [f"{s},40,{ok:.4f},0.0,{hit:.4f},1\n" for s, ok, hit in rows]
    (folder / "selection.csv").write_text(HEADER + "".join(lines))
    return folder


def test_best_and_last_evaluations_are_printed_and_drawn(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    a = _round(tmp_path / "a", [(25000, 0.2, 0.5), (50000, 0.6, 0.1), (75000, 0.4, 0.3)])
    # the first evaluation is written twice by a training (before and after its first round): the last copy counts
    b = _round(tmp_path / "b", [(25000, 0.1, 0.4), (25000, 0.3, 0.2), (50000, 0.25, 0.2)])
    out = tmp_path / "fig" / "curves.png"
    assert main(["--run", f"plain={a}", "--run", f"with=margin={b}", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "plain: best robot success 0.600 at 50000 steps (collisions 0.100); last 0.400 at 75000" in text
    assert "with=margin: best robot success 0.300 at 25000 steps (collisions 0.200); last 0.250 at 50000" in text
    with Image.open(out) as picture:
        assert picture.size[0] > 400 and picture.size[1] > 300


def test_a_run_without_its_table_or_label_is_refused(tmp_path: Path) -> None:
    with pytest.raises(SystemExit, match=r"selection\.csv does not exist"):
        main(["--run", f"x={tmp_path}", "--out", str(tmp_path / "c.png")])
    with pytest.raises(SystemExit, match="expected LABEL=FOLDER"):
        main(["--run", str(tmp_path), "--out", str(tmp_path / "c.png")])
    assert not (tmp_path / "c.png").exists()
