"""How much of this machine's CPU its hypervisor took meanwhile (steal time).

On a virtual machine the host may run other guests on the cores this one believes it has; the
guest's kernel counts the time its virtual CPUs were ready but not running as *steal*
(``/proc/stat``, 8th field), and a real-time run loses deadlines meanwhile: on this project's
2-core machine a composed run during which ``vmstat`` showed 7-18 % steal missed 10.9 % of its
deadlines, one with 0.12 % steal ten minutes later 0.45 % (docs/performance.md, fortieth
session). The graph's idle cores poll rather than halt (:mod:`dcsms_ros.ros.cpulatency`): with
them polling the runs' steal was lower in 13 of 18 pairs. ``dcsms up`` reads the counters
before and after a run and puts the share in its summary
(:attr:`~dcsms_ros.protocols.runstats.RunSummary.steal`), so a user can tell a loaded host
from a graph that cannot keep up.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

#: The kernel's CPU accounting (its first line sums every CPU).
PROC_STAT = Path("/proc/stat")


@dataclass(frozen=True)
class CpuTimes:
    """This machine's CPU time since boot, every CPU summed, in clock ticks.

    Attributes
    ----------
    steal : int
        Ticks the hypervisor ran something else while a CPU of this machine was ready.
    idle : int
        Ticks no CPU had work (idle and waiting for I/O).
    total : int
        Ticks of every kind (user, nice, system, idle, iowait, irq, softirq, steal).
    """

    steal: int
    idle: int
    total: int


def read_cpu_times(path: Path = PROC_STAT) -> CpuTimes | None:
    """The counters of ``path`` (``/proc/stat``), or None where it cannot be read or has no
    steal field (not Linux, a kernel before 2.6.11)."""
    try:
        first = path.read_text().split("\n", 1)[0].split()
    except OSError:
        return None
    if len(first) < 9 or first[0] != "cpu":
        return None
    try:
        # guest and guest_nice (fields 9-10) are already inside user and nice
        ticks = [int(x) for x in first[1:9]]
    except ValueError:
        return None
    return CpuTimes(steal=ticks[7], idle=ticks[3] + ticks[4], total=sum(ticks))


def steal_fraction(before: CpuTimes | None, after: CpuTimes | None) -> float | None:
    """The share (0 to 1) of the machine's CPU time between ``before`` and ``after`` that was
    stolen; None if either is unknown or no tick passed."""
    if before is None or after is None:
        return None
    total = after.total - before.total
    if total <= 0:
        return None
    return max(after.steal - before.steal, 0) / total


def busy_fraction(before: CpuTimes | None, after: CpuTimes | None) -> float | None:
    """The share (0 to 1) of the machine's CPU time between ``before`` and ``after`` that was
    not idle (steal counts as busy: the cores were not free); None as :func:`steal_fraction`."""
    if before is None or after is None:
        return None
    total = after.total - before.total
    if total <= 0:
        return None
    return max(total - (after.idle - before.idle), 0) / total


def percents(shares: list[float | None], digits: int = 1) -> str:
    """``shares`` as percentages joined by " / " (``?`` where one is unknown)."""
    return " / ".join("?" if s is None else f"{100 * s:.{digits}f}" for s in shares)


__all__ = ["PROC_STAT", "CpuTimes", "busy_fraction", "percents", "read_cpu_times",
           "steal_fraction"]
