"""DDS domains of one machine, shared by its users: a twin on loopback takes one that nothing else here uses.

Two deployments on one host (two users, two ``dvc repro`` loops in two clones) must not hear each other's robots.
A fleet file that gives no ``network.domain_id`` lets each deployment take a free domain of `FREE_DOMAINS`; one that
pins a domain takes that one. Either way the deployment holds the domain's lease for as long as it runs: an
exclusive ``flock`` on ``<tmp>/mrl-dds-domain-<id>.lock`` (a file every user can open; the kernel lets the lock go
when the process ends, however it ends). A pinned domain whose lease another process holds is refused by name
before anything starts (:func:`pinned_domain_is_free`); the deployment's own check for strays on the domain
(participants that hold no lease: a twin started by hand, another ROS 2 program) follows as before.
"""

from __future__ import annotations

import errno
import fcntl
import os
import tempfile
from dataclasses import dataclass
from pathlib import Path

from pipeline.errors import RuntimeFault

FREE_DOMAINS = range(160, 233)
"""Domains a deployment takes for itself: clear of ROS's default (0), of the low ids labs pin by hand and of the
tests' own (tests/domains.py); 232 is the highest Cyclone DDS maps to ports."""


class NoFreeDomainError(RuntimeError):
    """Every domain of `FREE_DOMAINS` is leased on this machine."""


def lock_path(domain_id: int) -> Path:
    return Path(tempfile.gettempdir()) / f"mrl-dds-domain-{domain_id}.lock"


@dataclass
class DomainLease:
    """A domain held for this process: `release` (or the process's end) lets it go."""

    domain_id: int
    fd: int

    def release(self) -> None:
        if self.fd >= 0:
            os.close(self.fd)  # closing the descriptor drops the flock
            self.fd = -1

    def __enter__(self) -> DomainLease:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


def try_lease(domain_id: int) -> DomainLease | None:
    """The domain's lease if no other process holds it, else None."""
    path = lock_path(domain_id)
    old = os.umask(0)
    try:
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)  # another user's deployment must be able to lock it too
    except PermissionError:
        fd = os.open(path, os.O_RDONLY)
    finally:
        os.umask(old)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError as exc:
        os.close(fd)
        if exc.errno in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
            return None
        raise
    return DomainLease(domain_id, fd)


def lease_free_domain() -> DomainLease:
    """The first domain of `FREE_DOMAINS` (starting at a place of this process's own, so that deployments started
    together try different ones first) whose lease nobody holds.

    Raises:
        NoFreeDomainError: every one is held.
    """
    count = len(FREE_DOMAINS)
    first = os.getpid() % count
    for k in range(count):
        lease = try_lease(FREE_DOMAINS[(first + k) % count])
        if lease is not None:
            return lease
    raise NoFreeDomainError(
        f"every DDS domain of {FREE_DOMAINS.start}-{FREE_DOMAINS.stop - 1} is held by another deployment on this "
        "machine; give the fleet file a network.domain_id outside that range"
    )


def pinned_domain_is_free(domain_id: int) -> bool:
    """Whether no other process here holds the lease of `domain_id` (tried and let go at once)."""
    lease = try_lease(domain_id)
    if lease is None:
        return False
    lease.release()
    return True


class DomainHeld(RuntimeFault):
    """A pinned DDS domain that another deployment on this machine holds now."""

    def __init__(self, domain_id: int, fleet_source: str) -> None:
        self.domain_id = domain_id
        super().__init__(
            f"DDS domain {domain_id} already has another deployment on this machine (its lease: "
            f"{lock_path(domain_id)}): the fleet {fleet_source} pins it; give the fleet file another "
            "network.domain_id, or none (a twin then takes a free domain)"
        )


def check_pinned_domain(domain_id: int | None, fleet_source: str) -> None:
    """Before work that ends in a deployment (a training): DomainHeld where the fleet pins a domain another
    deployment on this machine holds now, so that the clash is not found only when the deployment starts."""
    if domain_id is not None and not pinned_domain_is_free(domain_id):
        raise DomainHeld(domain_id, fleet_source)
