"""The CPU wake-up latency a real-time process may ask the kernel for (PM QoS), opt-in.

A hot loop under SCHED_FIFO sleeps between samples and its core goes idle; how fast an idle
core wakes for the thread's timer depends on the idle state the kernel picked (on bare metal a
deep C-state takes tens to hundreds of us to leave). The kernel's ``/dev/cpu_dma_latency``
takes a process's tolerated wake-up latency (a 32-bit integer, us), holds it while the file
stays open, applies the smallest request of all processes and withdraws a request when its
process closes the file or dies. ``cyclictest`` asks for 0 us by default. Opening it needs root.

``DCSMS_CPU_LATENCY_US=N`` makes a hot loop under SCHED_FIFO hold N us while it runs; unset
(the default) leaves the kernel's choice. Why not by default, measured on this package's
reference machine (a KVM guest whose idle state is a halt; docs/performance.md, "The machine's
floor"): holding 0 us made a thread that only sleeps to 2 kHz deadlines wake 15 instead of 37
us after them at the median (p99 40 instead of 81 us) and the composed graph's control latency
p50 lower in 11 of 13 alternating pairs (0.13-0.19 against 0.15-0.24 ms), but its late samples
were not fewer (lower in 6 of 13; median 0.45 against 0.39 % of 40,000) and 5 of its 13 runs
had stale forces (3-23 each) against none of the 13 without: the idle cores that poll instead
of halting keep both virtual CPUs busy on the host.
"""

from __future__ import annotations

import os
import struct
from pathlib import Path

#: The kernel's PM QoS request file for the CPUs' wake-up latency.
PM_QOS_PATH = Path("/dev/cpu_dma_latency")
#: Environment variable with the wake-up latency (us) to hold under SCHED_FIFO.
CPU_LATENCY_ENV = "DCSMS_CPU_LATENCY_US"


def latency_from_env() -> tuple[int | None, str | None]:
    """The wake-up latency (us) ``$DCSMS_CPU_LATENCY_US`` asks for (None: unset, ``off`` or
    bad; leave the kernel's) and a warning for a bad value; never raises."""
    text = os.environ.get(CPU_LATENCY_ENV, "").strip()
    if not text or text.lower() == "off":
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
                      f"cores keep the kernel's idle states")
