"""Another host on this machine: a network namespace joined to this one by a veth pair, for measurements and tests
of robots on their own computers (needs root and iproute2's ``ip``; the kernel's namespaces, no netem).

:func:`other_host` makes one (addresses of its own in ``10.231.x.0/24``, x free here) and removes it afterwards,
however the block ends; :class:`RemoteProcess` runs a program over there and keeps its output.
"""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass

from pipeline.errors import MrlError

SUBNET = "10.231"
"""The veth pair's /24 is SUBNET.<x>.0, x picked per host (.1 here, .2 on the other host)."""


class HostsUnavailable(MrlError):
    """This machine does not let a second host be made (not root, no ``ip``, namespaces refused); says why."""


@dataclass(frozen=True)
class OtherHost:
    """A network namespace standing in for another host, reached from here over a veth pair."""

    name: str
    here_if: str
    """The veth end in this (the root) namespace."""
    there_if: str
    here_addr: str
    there_addr: str

    def command(self, *args: str) -> list[str]:
        """`args` run inside the other host."""
        return ["ip", "netns", "exec", self.name, *args]

    def link(self, up: bool) -> None:
        """Take the link between the hosts down or bring it up again (this end of the pair)."""
        done = ip("link", "set", self.here_if, "up" if up else "down")
        if done.returncode != 0:
            raise HostsUnavailable(f"ip link set {self.here_if}: {done.stderr.strip()}")


def ip(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(["ip", *args], capture_output=True, text=True, timeout=30, check=False)


def _free_subnet() -> int:
    """An x of SUBNET.x.0/24 that no interface here uses, starting from one this process's id picks."""
    used = ip("-4", "-o", "addr", "show").stdout
    for k in range(250):
        x = (os.getpid() + k) % 250 + 1
        if f" {SUBNET}.{x}." not in used:
            return x
    raise HostsUnavailable(f"no free /24 in {SUBNET}.0.0/16 for the veth pair")


def _remove(host: OtherHost) -> None:
    ip("netns", "del", host.name)  # takes its veth end, and so the pair, along
    if ip("link", "show", host.here_if).returncode == 0:
        ip("link", "del", host.here_if)


@contextmanager
def other_host(tag: str = "") -> Iterator[OtherHost]:
    """A namespace ``mrl-host-<pid><tag>`` with a veth pair SUBNET.x.1 (here) <-> SUBNET.x.2 (there), both ends and
    its loopback up; removed afterwards. HostsUnavailable where this machine does not allow it."""
    if shutil.which("ip") is None:
        raise HostsUnavailable("network namespaces: the ip command (iproute2) is not installed")
    if os.geteuid() != 0:
        raise HostsUnavailable("network namespaces: ip netns needs root")
    pid = os.getpid()
    x = _free_subnet()
    host = OtherHost(
        f"mrl-host-{pid}{tag}", f"mrlh{pid}{tag}a", f"mrlh{pid}{tag}b", f"{SUBNET}.{x}.1", f"{SUBNET}.{x}.2"
    )
    made = ip("netns", "add", host.name)
    if made.returncode != 0:
        raise HostsUnavailable(f"network namespaces: ip netns add {host.name} failed: {made.stderr.strip()}")
    try:
        steps = [
            ("link", "add", host.here_if, "type", "veth", "peer", "name", host.there_if),
            ("link", "set", host.there_if, "netns", host.name),
            ("addr", "add", f"{host.here_addr}/24", "dev", host.here_if),
            ("link", "set", host.here_if, "up"),
            ("netns", "exec", host.name, "ip", "addr", "add", f"{host.there_addr}/24", "dev", host.there_if),
            ("netns", "exec", host.name, "ip", "link", "set", host.there_if, "up"),
            ("netns", "exec", host.name, "ip", "link", "set", "lo", "up"),
        ]
        for step in steps:
            done = ip(*step)
            if done.returncode != 0:
                raise HostsUnavailable(f"network namespaces: ip {' '.join(step)} failed: {done.stderr.strip()}")
        yield host
    finally:
        _remove(host)


class RemoteProcess:
    """A process on the other host; its output (stdout and stderr) is kept, a line starting with `ready` awaited.
    Its standard input is a pipe only this process holds (the twin's ``--exit-with-parent`` lifeline)."""

    def __init__(self, host: OtherHost, args: list[str], env: dict[str, str], ready: str = "") -> None:
        self.proc = subprocess.Popen(
            host.command(*args),
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            env=env,
        )
        self.lines: list[str] = []
        self.ready = threading.Event()
        self._ready_text = ready
        threading.Thread(target=self._pump, daemon=True).start()

    def _pump(self) -> None:
        assert self.proc.stdout is not None  # opened as a pipe above
        for line in self.proc.stdout:
            self.lines.append(line.rstrip())
            if self._ready_text and line.startswith(self._ready_text):
                self.ready.set()

    def wait_ready(self, timeout_s: float) -> None:
        """Until its ready line; HostsUnavailable naming its last output where it exits or takes too long."""
        deadline = time.monotonic() + timeout_s
        while not self.ready.wait(0.05):
            if self.proc.poll() is not None or time.monotonic() > deadline:
                raise HostsUnavailable(f"{self.proc.args!r} did not report ready: {' | '.join(self.lines[-20:])}")

    def stop(self) -> int:
        """Close its lifeline, then SIGINT (SIGKILL after 15 s); its exit code."""
        if self.proc.stdin is not None and not self.proc.stdin.closed:
            self.proc.stdin.close()
        if self.proc.poll() is None:
            self.proc.send_signal(signal.SIGINT)
            try:
                self.proc.wait(15)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        return self.proc.returncode


def dds_environment() -> dict[str, str]:
    """The environment of a DDS process on the other host (its one interface is the veth: nothing to name)."""
    env = dict(os.environ)
    env.pop("CYCLONEDDS_URI", None)
    return env
