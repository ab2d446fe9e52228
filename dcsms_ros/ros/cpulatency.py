"""The CPU wake-up latency a real-time hot loop holds while it runs (PM QoS), 0 us by default.

A hot loop under SCHED_FIFO sleeps between samples and its core goes idle; how fast an idle
core wakes for the thread's timer, and how warm it finds its caches, depends on the idle state
the kernel picked (on bare metal a deep C-state takes tens to hundreds of us to leave and
loses the caches; in a virtual machine an idle virtual CPU halts and leaves its physical core to
the host). The kernel's ``/dev/cpu_dma_latency`` takes a process's tolerated wake-up latency
(a 32-bit integer, us), holds it while the file stays open, applies the smallest request of all
processes and withdraws a request when its process closes the file or dies. ``cyclictest``
asks for 0 us by default, and so does a hot loop under SCHED_FIFO here: idle cores then poll
instead of halting. ``DCSMS_CPU_LATENCY_US=N`` asks for N us instead, ``off`` for nothing (the
kernel's choice). Opening the file needs root; refused, the run goes on with a warning.

Measured on this package's reference machine, a KVM guest whose idle state is a halt
(docs/performance.md, fortieth and twelfth sessions): the same Python work run every 500 us
took 2-2.5x the CPU it takes back to back (77-96 against 38 us), 43-59 us with 0 us held. The
user's recorded real-time command, 9 alternating pairs per deployment on a contended host:
late + stale samples fewer with 0 us held in 8 of 9 pairs per process (late 3.47 against 0.79 %
pooled; the hypervisor's steal time during the runs 0.04-9.4 % without it, 0.05-1.3 % with it)
and in 7 of 9 composed (1.81 against 0.62 %). On a quiet host (twelfth session, 13 composed
pairs) it made control latency p50 lower in 11 but late samples fewer in only 6, and 5 of those
13 runs had 3-23 stale forces against none without: a cost of a few samples in a quiet hour
against several times fewer late samples in a busy one. Polling idle cores keep the machine's
CPUs busy on the host (and use power on bare metal) while a real-time graph runs.
"""

from __future__ import annotations

import os
import struct
from pathlib import Path

#: The kernel's PM QoS request file for the CPUs' wake-up latency.
PM_QOS_PATH = Path("/dev/cpu_dma_latency")
#: Environment variable with the wake-up latency (us) to hold under SCHED_FIFO, or ``off``.
CPU_LATENCY_ENV = "DCSMS_CPU_LATENCY_US"
#: The wake-up latency (us) held when the variable is unset.
DEFAULT_US = 0


def latency_from_env() -> tuple[int | None, str | None]:
    """The wake-up latency (us) ``$DCSMS_CPU_LATENCY_US`` asks for (:data:`DEFAULT_US` when
    unset; None: ``off`` or bad, leave the kernel's) and a warning for a bad value; never
    raises."""
    text = os.environ.get(CPU_LATENCY_ENV, "").strip()
    if not text:
        return DEFAULT_US, None
    if text.lower() == "off":
        return None, None
    try:
        us = int(text)
        if us < 0:
            raise ValueError
    except ValueError:
        return None, (f"{CPU_LATENCY_ENV}={text!r}: not a whole number of us >= 0; the "
                      f"kernel's wake-up latency kept")
    return us, None


class CpuLatencyRequest:
    """One held request for a CPU wake-up latency of :attr:`us` microseconds; :meth:`close`
    (idempotent) withdraws it.

    Parameters
    ----------
    us : int
        Tolerated wake-up latency (us), >= 0.
    path : Path, optional
        The PM QoS file (:data:`PM_QOS_PATH`).

    Raises
    ------
    OSError
        The file is missing or may not be opened (not root).
    """

    def __init__(self, us: int, path: Path = PM_QOS_PATH) -> None:
        if us < 0:
            raise ValueError(f"CPU wake-up latency {us} us: must be >= 0")
        self.us = us
        self.path = path
        self._fd: int | None = os.open(path, os.O_WRONLY)
        try:
            os.write(self._fd, struct.pack("i", us))
        except OSError:
            self.close()
            raise

    @property
    def held(self) -> bool:
        """Whether the request still holds."""
        return self._fd is not None

    def close(self) -> None:
        """Withdraw the request."""
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None


def hold_from_env(path: Path = PM_QOS_PATH) -> tuple[CpuLatencyRequest | None, str | None]:
    """Hold the wake-up latency ``$DCSMS_CPU_LATENCY_US`` asks for through ``path``; returns
    the request (None when not asked for or refused) and a warning (a bad value, or refused:
    the run goes on with the kernel's idle states)."""
    us, warning = latency_from_env()
    if us is None:
        return None, warning
    try:
        return CpuLatencyRequest(us, path), None
    except OSError as exc:
        return None, (f"CPU wake-up latency {us} us not held ({path}: {exc.strerror}); idle "
                      f"cores keep the kernel's idle states ({CPU_LATENCY_ENV}=off: do not ask)")
