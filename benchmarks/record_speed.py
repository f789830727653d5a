"""Recorder and reader speed on odometry messages: ``python benchmarks/record_speed.py [--messages N]``.

Each rate is printed with the limit measured in the same run on the same messages: for
``write`` the bare CDR serialization by the message store, for ``messages`` the bare CDR
decoding, for ``write_cdr`` and ``raw`` (no CDR work) the limit is reported as messages/s only.
Last line: ``ratio=<write/serialize> write_per_s=<write>``.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np

from pipeline.messages import convert as C
from pipeline.messages import fleet_topics, message_store
from pipeline.messages import topics as T
from pipeline.record import McapLog, McapRecorder


def rate(n: int, seconds: float) -> float:
    return n / seconds if seconds > 0 else float("inf")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--messages", type=int, default=200_000)
    args = parser.parse_args()
    n = args.messages
    s = message_store()
    rng = np.random.default_rng(0)
    pool = [
        C.odometry(i * 20_000_000, f"robot_{i % 3 + 1}", rng.normal(size=3), (0.2, 0.1), store=s) for i in range(1000)
    ]
    topics = fleet_topics(["robot_1", "robot_2", "robot_3"])
    names = [f"/robot_{i % 3 + 1}/odom" for i in range(1000)]

    t = time.perf_counter()
    blobs = [s.serialize(pool[i % 1000], T.ODOMETRY) for i in range(n)]
    serialize = rate(n, time.perf_counter() - t)

    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "speed.mcap"
        t = time.perf_counter()
        with McapRecorder(path, topics) as rec:
            for i in range(n):
                rec.write(names[i % 1000], pool[i % 1000], i * 1000)
        write = rate(n, time.perf_counter() - t)
        size = path.stat().st_size

        cdr_path = Path(folder) / "speed_cdr.mcap"
        t = time.perf_counter()
        with McapRecorder(cdr_path, topics) as rec:
            for i in range(n):
                rec.write_cdr(names[i % 1000], blobs[i], i * 1000)
        write_cdr = rate(n, time.perf_counter() - t)

        t = time.perf_counter()
        for _ in McapLog(path).raw():
            pass
        raw = rate(n, time.perf_counter() - t)

        t = time.perf_counter()
        for blob in blobs:
            s.deserialize(blob, T.ODOMETRY)
        deserialize = rate(n, time.perf_counter() - t)

        t = time.perf_counter()
        for _ in McapLog(path).messages():
            pass
        messages = rate(n, time.perf_counter() - t)

    print(f"messages={n} file_bytes={size} bytes_per_message={size / n:.1f}")
    print(f"serialize_per_s={serialize:.0f} write_per_s={write:.0f} ratio={write / serialize:.3f}")
    print(f"write_cdr_per_s={write_cdr:.0f}")
    print(f"deserialize_per_s={deserialize:.0f} messages_per_s={messages:.0f} ratio={messages / deserialize:.3f}")
    print(f"raw_per_s={raw:.0f}")
    print(f"ratio={write / serialize:.3f} write_per_s={write:.0f}")


if __name__ == "__main__":
    main()
