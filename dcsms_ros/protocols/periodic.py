"""Which periodic jobs are due at a tick: many housekeeping periods served by one timer.

A process's housekeeping (reports, the trip judge, the recorder's flush and discovery) used one
timer per job, and every timer firing on its own phase woke the executor's thread, which then
rebuilt rclpy's wait set over every entity of the process in Python while holding the GIL that
the real-time driver thread needs (docs/performance.md, "GIL hand-offs"). One timer at the
shortest period serves them all, so the jobs ride on the wake-ups of the most frequent one.

What delays the driver is a long hold of the GIL: it shares the GIL with a busy executor
thread, so a burst of executor work longer than the driver's slack makes samples late, and
short ones are absorbed. The jobs slower than the tick are therefore staggered: job ``j`` of
period ``p_j`` is due at ``t0 + o_j + n * p_j`` (n = 1, 2, ...) with its offset ``o_j`` a
different whole number of ticks for each such job (as far as the period allows), so that a tick
runs the fastest job and at most about one other instead of all of them at once.

A tick at ``now`` runs a job when ``now`` is past its due time less half a tick (timer jitter
must not push a job a whole tick late), then schedules its next due time; a job that fell more
than a period behind skips what it missed (as an rcl timer does) instead of running in a burst.
No ROS here.
"""

from __future__ import annotations

from collections.abc import Sequence


class PeriodicSchedule:
    """Due times of jobs with the given periods (s), ticked every :attr:`tick_s`.

    Parameters
    ----------
    periods_s : sequence of float
        Period of each job, s (> 0).
    t0 : float
        Start time, s: job ``j`` is first due at ``t0 + periods_s[j] + offsets[j]``.
    """

    def __init__(self, periods_s: Sequence[float], t0: float) -> None:
        if not periods_s or min(periods_s) <= 0.0:
            raise ValueError(f"periods must be positive, got {list(periods_s)}")
        self.periods = [float(p) for p in periods_s]
        #: The period of the one timer: the shortest job period, s.
        self.tick_s = min(self.periods)
        #: Offset of each job's phase, s (0 for the jobs at the tick's period).
        self.offsets = self._stagger()
        self._next = [t0 + p + o for p, o in zip(self.periods, self.offsets, strict=True)]
        #: runs skipped because a job fell more than a period behind
        self.skipped = [0] * len(self.periods)

    def _stagger(self) -> list[float]:
        """Offsets (s): each slower job, most frequent first, on the tick phase that the jobs
        placed before it load least (over the longest period in ticks)."""
        slots = [max(int(round(p / self.tick_s)), 1) for p in self.periods]
        window = max(slots)
        load = [0] * window
        offsets = [0.0] * len(self.periods)
        for j in sorted(range(len(slots)), key=lambda i: slots[i]):
            n = slots[j]
            if n < 2:
                continue
            best = min(range(n), key=lambda o: (max(load[o::n]), o))
            for k in range(best, window, n):
                load[k] += 1
            offsets[j] = best * self.tick_s
        return offsets

    def due(self, now: float) -> list[int]:
        """The jobs to run at a tick at ``now`` (s), in job order; advances their due times."""
        half = 0.5 * self.tick_s
        out = []
        for j, due_at in enumerate(self._next):
            if now < due_at - half:
                continue
            out.append(j)
            p = self.periods[j]
            nxt = due_at + p
            if nxt <= now + half:  # it would run again at the next tick: skip, keep the phase
                missed = int((now + half - nxt) // p) + 1
                self.skipped[j] += missed
                nxt += missed * p
            self._next[j] = nxt
        return out


__all__ = ["PeriodicSchedule"]
