"""ROS domain ids for tests: each test of a run its own, never one another run on this machine
holds at the same time (``lease_domains``)."""

from __future__ import annotations

import fcntl
import os
import random
import tempfile
from pathlib import Path

# Every test of one run gets a different domain (Fast DDS allows 0..232 with default ports), in an
# order the pid seeds. Two runs side by side on one machine must not share a domain at the same
# time: their graphs answer each other's samples (measured 2026-11-28, two runs of one lockstep
# test in one domain: 4 of 12 failed, with a foreign zero force applied or their own samples
# judged old). A run therefore holds a lock file per domain in use, shared by every run here.
# Single ids come from SINGLE; consecutive blocks (the bench smoke's 17 graphs) from BLOCKS: after
# a run has scattered ~90 single ids over the whole range no 17 consecutive ones were left (CI,
# 2026-11-28).
MAX_DOMAIN = 232
SINGLE = range(1, 196)
BLOCKS = range(196, MAX_DOMAIN + 1)
LEASE_DIR = Path(tempfile.gettempdir()) / "dcsms-test-domains"
_ORDER = random.Random(os.getpid()).sample(SINGLE, len(SINGLE))
_USED: set[int] = set()


class DomainLease:
    """ROS domain ids ``first`` .. ``first + count - 1``, held by this run: each id's lock file
    is locked (``flock``) until :meth:`release` (or the process's end)."""

    def __init__(self, first: int, fds: list[int]) -> None:
        self.first, self._fds = first, fds

    def release(self) -> None:
        """Let other runs use the ids (this run never takes them again)."""
        for fd in self._fds:
            os.close(fd)
        self._fds = []


def _lock(d: int) -> int | None:
    fd = os.open(LEASE_DIR / f"{d}.lock", os.O_CREAT | os.O_RDWR, 0o666)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        os.close(fd)
        return None
    return fd


def lease_domains(count: int = 1) -> DomainLease:
    """``count`` consecutive domain ids that no test of this run has had and no other run
    holds now."""
    LEASE_DIR.mkdir(exist_ok=True)
    starts = _ORDER if count == 1 else range(BLOCKS.start, BLOCKS.stop - count + 1)
    for first in starts:
        ids = range(first, first + count)
        if any(d in _USED for d in ids):
            continue
        fds: list[int] = []
        for d in ids:
            fd = _lock(d)
            if fd is None:
                break
            fds.append(fd)
        if len(fds) == count:
            _USED.update(ids)
            return DomainLease(first, fds)
        DomainLease(first, fds).release()
    raise RuntimeError(f"no {count} free ROS domain id(s) left for this test run "
                       f"(used {len(_USED)}; other runs hold {LEASE_DIR})")
