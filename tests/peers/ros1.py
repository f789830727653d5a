"""A private ROS 1 master for the ROS 1 tier: Debian's ``rosmaster`` on a free loopback port.

:func:`missing` says why the tier cannot run here (rospy or rosmaster absent); :func:`master`
starts ``rosmaster --core -p PORT`` with its logs in a folder of its own and stops it on exit.
rospy allows one node per process, bound to one master: a test process uses one master for all its
ROS 1 tests (the session fixture ``ros1_master``).
"""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

from pipeline.ros.errors import TransportError
from pipeline.ros.ros1 import check_master, ros1_missing


def missing() -> str | None:
    """Why the ROS 1 tier cannot run here (None: it can)."""
    why = ros1_missing()
    if why is None and shutil.which("rosmaster") is None:
        why = "rosmaster is not installed (apt-get install ros-core python3-rospy)"
    return None if why is None else f"{why} (.ci/run installs Debian's ROS 1)"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def environment(uri: str, home: Path) -> dict[str, str]:
    """The environment of a ROS 1 process on master `uri` with its logs under `home`."""
    return {**os.environ, "ROS_MASTER_URI": uri, "ROS_HOME": str(home), "ROS_LOG_DIR": str(home / "log")}


@contextmanager
def master(home: Path, timeout_s: float = 15.0) -> Iterator[str]:
    """A rosmaster on a free loopback port while the block runs; yields its URI."""
    home.mkdir(parents=True, exist_ok=True)
    port = free_port()
    uri = f"http://127.0.0.1:{port}"
    out = (home / "rosmaster.log").open("w")
    proc = subprocess.Popen(
        ["rosmaster", "--core", "-p", str(port)], env=environment(uri, home), stdout=out, stderr=subprocess.STDOUT
    )
    try:
        deadline = time.monotonic() + timeout_s
        while True:
            try:
                check_master(uri, timeout_s=1.0)
                break
            except TransportError:
                if proc.poll() is not None or time.monotonic() > deadline:
                    raise RuntimeError(
                        f"rosmaster on port {port} did not start: {(home / 'rosmaster.log').read_text()}"
                    ) from None
                time.sleep(0.1)
        yield uri
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        out.close()
