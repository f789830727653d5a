"""The golden recording: its decoding is fixed, and regenerating it gives the same bytes."""

from __future__ import annotations

import json
import warnings

from mcap.reader import make_reader

from tests.golden.make_golden import (
    GOLDEN_JSON,
    GOLDEN_MCAP,
    GOLDEN_V1_JSON,
    GOLDEN_V1_MCAP,
    decode,
    to_json,
    write_golden,
)


def test_golden_file_decodes_to_the_committed_json():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got = decode(GOLDEN_MCAP)
    expected = json.loads(GOLDEN_JSON.read_text())
    assert got["messages"] == expected["messages"]
    assert got == expected
    assert to_json(got) == GOLDEN_JSON.read_text()


def test_the_golden_file_of_the_first_format_still_decodes_as_it_did():
    # written before EpisodeEvent had its seed field: its messages decode by the schema in the file
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        got = decode(GOLDEN_V1_MCAP)
    assert to_json(got) == GOLDEN_V1_JSON.read_text()
    starts = [m["msg"] for m in got["messages"] if m["topic"] == "/mrl/episode" and m["msg"]["event"] == 0]
    assert starts and all(s["detail"] == "seed=7" and "seed" not in s for s in starts)


def test_golden_file_covers_the_contract():
    expected = json.loads(GOLDEN_JSON.read_text())
    assert 30 <= len(expected["messages"]) <= 100
    assert len(expected["topics"]) == 17 and len(set(expected["topics"].values())) == 12
    assert {"params", "session", "versions"} <= set(expected["metadata"])
    times = [m["log_time_ns"] for m in expected["messages"]]
    assert times == sorted(times)
    with open(GOLDEN_MCAP, "rb") as f:
        summary = make_reader(f, validate_crcs=True).get_summary()
    assert summary is not None and len(summary.chunk_indexes) >= 3


def test_regenerating_gives_identical_bytes(tmp_path):
    first, second = tmp_path / "a.mcap", tmp_path / "b.mcap"
    write_golden(first)
    write_golden(second)
    assert first.read_bytes() == second.read_bytes()
    assert first.read_bytes() == GOLDEN_MCAP.read_bytes(), (
        "the recorder writes different bytes than the committed golden file; if the format change is "
        "intended (or mcap/zstandard/rosbags changed), run: python -m tests.golden.make_golden"
    )
