"""The test runs' ROS domain leases (rosdomains.py): two runs side by side never share a domain."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap

from rosdomains import _ORDER, _USED, BLOCKS, LEASE_DIR, SINGLE, _lock, lease_domains


def test_a_leased_block_is_locked_until_released_and_never_leased_again_by_this_run():
    lease = lease_domains(3)
    ids = range(lease.first, lease.first + 3)
    # blocks never take the single ids, which a run scatters over their whole range
    assert set(ids) <= set(BLOCKS) and not set(BLOCKS) & set(SINGLE)
    assert all(d in _USED for d in ids)
    assert [_lock(d) for d in ids] == [None] * 3  # held: another open file cannot lock it
    lease.release()
    fds = [_lock(d) for d in ids]
    assert None not in fds
    again = lease_domains()
    assert again.first not in ids
    again.release()
    for fd in fds:
        if fd is not None:
            os.close(fd)


def test_a_domain_another_process_holds_is_skipped():
    nxt = next(d for d in _ORDER if d not in _USED)
    holder = subprocess.Popen([sys.executable, "-c", textwrap.dedent(f"""
        import fcntl, os, sys
        fd = os.open({str(LEASE_DIR / f"{nxt}.lock")!r}, os.O_CREAT | os.O_RDWR)
        fcntl.flock(fd, fcntl.LOCK_EX)
        print("held", flush=True)
        sys.stdin.read()
        """)], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
        lease = lease_domains()
        assert lease.first != nxt
        lease.release()
        assert nxt not in _USED  # skipped, still free for this run once the other lets go
    finally:
        holder.communicate("", timeout=10)
