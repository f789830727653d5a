"""Every verb of `mrl` checks its --out before any work: a file in the way, a file among its parents, a place that
cannot be written: one line naming the option and the path, exit 2, no traceback, nothing created."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

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


def test_a_warning_is_shown_once_per_command(capsys):
    import io

    from pipeline.mrl import _warning_line

    stream = io.StringIO()
    show = _warning_line("info", stream)
    for _ in range(3):
        show(UserWarning("x.mcap: salvaged 10 messages"), UserWarning, "file", 1)
    show(UserWarning("y.mcap: salvaged 2 messages"), UserWarning, "file", 1)
    assert stream.getvalue().splitlines() == [
        "mrl info: warning: x.mcap: salvaged 10 messages",
        "mrl info: warning: y.mcap: salvaged 2 messages",
    ]


@pytest.mark.parametrize("value", ["-1", "233", "x"])
def test_deploy_domain_id_is_checked_by_the_parser(value, capsys):
    with pytest.raises(SystemExit) as done:
        main(["deploy", "--policy", "p", "--domain-id", value])
    assert done.value.code == 2 and "a DDS domain id, an integer from 0 to 232" in capsys.readouterr().err


def test_deploy_drive_is_checked_by_the_parser(capsys):
    with pytest.raises(SystemExit) as done:
        main(["deploy", "--policy", "p", "--fleet", "twin", "--drive", "wobble"])
    err = capsys.readouterr().err
    assert done.value.code == 2 and "--drive" in err and "'policy', 'excitation'" in err


def test_deploy_time_scale_is_a_number_or_auto(capsys):
    with pytest.raises(SystemExit) as done:
        main(["deploy", "--policy", "p", "--time-scale", "fast"])
    err = capsys.readouterr().err
    assert done.value.code == 2 and "--time-scale" in err and "a number of simulated seconds per second, or auto" in err


@pytest.mark.parametrize("value", ["fast", -1.0, 25])
def test_a_fleet_time_scale_other_than_a_number_or_auto_is_named(value, tmp_path):
    from pipeline.errors import ConfigError
    from pipeline.ros.fleet import load_fleet

    text = (Path(load_fleet.__code__.co_filename).parent / "fleets" / "twin.yaml").read_text()
    data = yaml.safe_load(text)
    data["twin"]["time_scale"] = value
    path = tmp_path / "fleet.yaml"
    path.write_text(yaml.safe_dump(data))
    with pytest.raises(ConfigError) as err:
        load_fleet(str(path))
    message = str(err.value)
    assert "twin.time_scale" in message and "or one of 'auto'" in message and str(path) in message
    data["twin"]["time_scale"] = "auto"
    path.write_text(yaml.safe_dump(data))
    assert load_fleet(str(path)).twin.time_scale == "auto"
