"""The fuzz tier: generated inputs against every reader of outside data. Each reader either reads an input or refuses
it with the pipeline's own error naming the file; no traceback from a library, no hang (5 s per input).

50 inputs per reader in the default suite, 500 in the slow tier (``-m slow``)."""

from __future__ import annotations

import tempfile
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pipeline.analysis.decode import decode
from pipeline.calibration.localize import OccupancyMap
from pipeline.core.scenario import load_scenario
from pipeline.errors import MrlError
from pipeline.record import McapLog, import_bag
from pipeline.ros.fleet import fleet_path, load_fleet
from pipeline.twin.profile import load_profile, profile_path
from tests.golden.make_golden import GOLDEN_MCAP
from tests.unit.test_record_bags import golden_raw, write_ros1, write_rosbag2

DEFAULT_EXAMPLES = 50
SLOW_EXAMPLES = 500
DEADLINE_MS = 5000


def fuzz(examples: int) -> Callable[[Callable[..., None]], Callable[..., None]]:
    return settings(
        max_examples=examples,
        deadline=DEADLINE_MS,
        suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large],
        derandomize=True,
    )


# -- byte mutations ---------------------------------------------------------------------------------------------

Mutation = tuple[str, int, int, bytes]


def mutations() -> st.SearchStrategy[list[Mutation]]:
    op = st.tuples(
        st.sampled_from(["truncate", "flip", "insert", "zero", "replace"]),
        st.integers(min_value=0, max_value=1 << 30),
        st.integers(min_value=1, max_value=64),
        st.binary(min_size=1, max_size=16),
    )
    return st.lists(op, min_size=1, max_size=4)


def mutate(data: bytes, ops: list[Mutation]) -> bytes:
    out = bytearray(data)
    for kind, where, length, extra in ops:
        if not out:
            break
        at = where % len(out)
        if kind == "truncate":
            del out[at:]
        elif kind == "flip":
            for k in range(at, min(len(out), at + length)):
                out[k] ^= 0xFF
        elif kind == "insert":
            out[at:at] = extra
        elif kind == "zero":
            out[at : at + length] = bytes(min(length, len(out) - at))
        else:
            out[at : at + len(extra)] = extra
    return bytes(out)


def refused_or_read(where: Path, read: Callable[[], Any]) -> None:
    """`read()` either succeeds or raises an MrlError whose message names `where` (its name at least)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            read()
        except MrlError as exc:
            assert where.name in str(exc), f"the error does not name {where}: {exc}"


def read_all(path: Path) -> None:
    log = McapLog(path)
    for _ in log.raw():
        pass
    log.message_counts()


@pytest.fixture(scope="module")
def sources(tmp_path_factory: pytest.TempPathFactory) -> dict[str, bytes]:
    root = tmp_path_factory.mktemp("fuzz_sources")
    raw = golden_raw()
    rosbag2 = write_rosbag2(root / "rosbag2", raw)
    (mcap,) = rosbag2.glob("*.mcap")
    ros1 = write_ros1(root / "session.bag", [m for m in raw if m.topic != "/mrl/episode" and "mrl" not in m.typename])
    return {
        "mcap": GOLDEN_MCAP.read_bytes(),
        "rosbag2_mcap": mcap.read_bytes(),
        "rosbag2_metadata": (rosbag2 / "metadata.yaml").read_bytes(),
        "ros1": ros1.read_bytes(),
    }


# -- the readers ---------------------------------------------------------------------------------------------


def check_mcap(sources: dict[str, bytes], examples: int) -> None:
    @fuzz(examples)
    @given(ops=mutations())
    def run(ops: list[Mutation]) -> None:
        with tempfile.TemporaryDirectory() as d:
            path = Path(d) / "fuzzed.mcap"
            path.write_bytes(mutate(sources["mcap"], ops))
            refused_or_read(path, lambda: read_all(path))

    run()


def check_rosbag2(sources: dict[str, bytes], examples: int) -> None:
    @fuzz(examples)
    @given(ops=mutations(), which=st.sampled_from(["rosbag2_mcap", "rosbag2_metadata"]))
    def run(ops: list[Mutation], which: str) -> None:
        with tempfile.TemporaryDirectory() as d:
            folder = Path(d) / "fuzzed_bag"
            folder.mkdir()
            meta = sources["rosbag2_metadata"]
            data = sources["rosbag2_mcap"]
            if which == "rosbag2_mcap":
                data = mutate(data, ops)
            else:
                meta = mutate(meta, ops)
            name = yaml.safe_load(sources["rosbag2_metadata"])["rosbag2_bagfile_information"]["relative_file_paths"][0]
            (folder / name).write_bytes(data)
            (folder / "metadata.yaml").write_bytes(meta)
            refused_or_read(folder, lambda: read_all(import_bag(folder, work_dir=Path(d) / "work").path))

    run()


def check_ros1(sources: dict[str, bytes], examples: int) -> None:
    @fuzz(examples)
    @given(ops=mutations())
    def run(ops: list[Mutation]) -> None:
        with tempfile.TemporaryDirectory() as d:
            path = Path(d) / "fuzzed.bag"
            path.write_bytes(mutate(sources["ros1"], ops))
            refused_or_read(path, lambda: read_all(import_bag(path, work_dir=Path(d) / "work").path))

    run()


CDR_TYPES = (
    "sensor_msgs/msg/LaserScan",
    "nav_msgs/msg/Odometry",
    "geometry_msgs/msg/Twist",
    "mrl_msgs/msg/EpisodeEvent",
)


def check_cdr(examples: int) -> None:
    @fuzz(examples)
    @given(
        typename=st.sampled_from(CDR_TYPES),
        bodies=st.lists(st.binary(max_size=600), min_size=1, max_size=4),
        fast=st.booleans(),
    )
    def run(typename: str, bodies: list[bytes], fast: bool) -> None:
        datas = [b"\x00\x01\x00\x00" + body for body in bodies]
        where = Path("fuzzed-topic")
        refused_or_read(where, lambda: decode(typename, datas, fast=fast, where=str(where)))

    run()


SCALARS = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(10**6), max_value=10**6),
    st.floats(allow_nan=True, allow_infinity=True),
    st.text(max_size=12),
)


def documents(base: dict[str, Any]) -> st.SearchStrategy[Any]:
    """YAML documents near `base`: keys dropped, values replaced by other scalars or containers, keys added."""
    keys = sorted(base)

    @st.composite
    def near(draw: st.DrawFn) -> Any:
        if draw(st.integers(0, 9)) == 0:  # now and then: not a mapping at all
            return draw(st.one_of(SCALARS, st.lists(SCALARS, max_size=3)))
        doc = dict(base)
        for key in draw(st.lists(st.sampled_from(keys), max_size=3)) if keys else []:
            doc.pop(key, None)
        for key in draw(st.lists(st.sampled_from(keys), max_size=3)) if keys else []:
            inner = base.get(key)
            if isinstance(inner, dict) and inner and draw(st.booleans()):
                sub = dict(inner)
                sub[draw(st.sampled_from(sorted(inner)))] = draw(SCALARS)
                doc[key] = sub
            else:
                doc[key] = draw(
                    st.one_of(
                        SCALARS,
                        st.lists(SCALARS, max_size=3),
                        st.dictionaries(st.text(max_size=5), SCALARS, max_size=2),
                    )
                )
        if draw(st.booleans()):
            doc[draw(st.text(min_size=1, max_size=8))] = draw(SCALARS)
        return doc

    return near()


def check_documents(name: str, base: dict[str, Any], reader: Callable[[Path], Any], examples: int) -> None:
    @fuzz(examples)
    @given(doc=documents(base), raw=st.booleans(), junk=st.binary(max_size=40))
    def run(doc: Any, raw: bool, junk: bytes) -> None:
        with tempfile.TemporaryDirectory() as d:
            path = Path(d) / f"fuzzed_{name}.yaml"
            if raw:
                path.write_bytes(yaml.safe_dump(doc).encode() + junk)
            else:
                path.write_text(yaml.safe_dump(doc))
            refused_or_read(path, lambda: reader(path))

    run()


def map_reader(path: Path) -> Any:
    return OccupancyMap.from_map_server(path)


def map_base(folder: Path) -> dict[str, Any]:
    image = np.full((20, 30), 254, dtype=np.uint8)
    image[0, :] = image[-1, :] = image[:, 0] = image[:, -1] = 0
    (folder / "floor.pgm").write_bytes(b"P5\n30 20\n255\n" + image.tobytes())
    return {"image": str(folder / "floor.pgm"), "resolution": 0.05, "origin": [0.0, 0.0, 0.0], "negate": 0,
            "occupied_thresh": 0.65, "free_thresh": 0.196}  # fmt: skip


def readers_of_documents(tmp: Path) -> dict[str, tuple[dict[str, Any], Callable[[Path], Any]]]:
    return {
        "profile": (yaml.safe_load(profile_path("lab").read_text()), lambda p: load_profile(p)),
        "fleet": (yaml.safe_load(fleet_path("twin").read_text()), lambda p: load_fleet(p)),
        "scenario": (yaml.safe_load(Path("pipeline/core/scenarios/obstacles.yaml").read_text()), load_scenario),
        "map": (map_base(tmp), map_reader),
    }


# -- the tests: the default tier and the slow one ---------------------------------------------------------------


@pytest.fixture
def repo(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(Path(__file__).resolve().parents[2])


@pytest.mark.parametrize("reader", ["mcap", "rosbag2", "ros1", "cdr"])
def test_recordings_and_messages_are_read_or_refused_by_name(sources, reader, repo):
    run_reader(sources, reader, DEFAULT_EXAMPLES)


@pytest.mark.parametrize("reader", ["profile", "fleet", "scenario", "map"])
def test_settings_files_are_read_or_refused_by_name(reader, tmp_path, repo):
    base, read = readers_of_documents(tmp_path)[reader]
    check_documents(reader, base, read, DEFAULT_EXAMPLES)


@pytest.mark.slow
@pytest.mark.parametrize("reader", ["mcap", "rosbag2", "ros1", "cdr"])
def test_recordings_and_messages_slow_tier(sources, reader, repo):
    run_reader(sources, reader, SLOW_EXAMPLES)


@pytest.mark.slow
@pytest.mark.parametrize("reader", ["profile", "fleet", "scenario", "map"])
def test_settings_files_slow_tier(reader, tmp_path, repo):
    base, read = readers_of_documents(tmp_path)[reader]
    check_documents(reader, base, read, SLOW_EXAMPLES)


def run_reader(sources: dict[str, bytes], reader: str, examples: int) -> None:
    if reader == "mcap":
        check_mcap(sources, examples)
    elif reader == "rosbag2":
        check_rosbag2(sources, examples)
    elif reader == "ros1":
        check_ros1(sources, examples)
    else:
        check_cdr(examples)
