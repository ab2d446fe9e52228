"""How old an input sample is when a real-time controller takes it.

A sample's stamp is its sample time on the plant's (or the rig's) clock, whose epoch the
controller does not know, so its age cannot be read as ``now - stamp``. The offset ``arrival -
stamp`` is that unknown epoch plus the path's delay; its minimum over a recent window is the
epoch plus the fastest delivery, and what a sample has above that minimum is its *excess
delay*: how much later than the path can deliver it the sample came. Judged so, the guard
needs no clock synchronisation between the plant (or a rig on another host) and the
controller, and it follows a drift between their clocks of up to ``limit / window`` (1e-3
with the defaults: crystals drift ~1e-5).

Why a controller on a rig needs it: its watchdog (:class:`.pacer.Watchdog`) notices an input
that stops, not one that arrives late. A controller process starved of CPU took twists 35-129
ms after their sample (docs/reliability.md, row 2) and answered them as fresh, and a rig's
actuator driver may apply whatever force comes; at table1's stage-2 crossover (14.6 Hz, 93 deg
of phase) 17.7 ms of delay is the whole phase margin. So against a rig the controller answers
an input later than its limit with zero force.

Not against the simulated plant, which ages every force itself from its sample's publication
(``PlantIO.arrived``) and whose schedule is elastic: it computes a backlog of up to 20
samples at once after a late wake-up, and beyond that drops the backlog and moves its
schedule on (:class:`.pacer.Pacer`), so a stamp does not tell when its sample was published.
Measured, one process per node: the guard judged 5,321 of 5,470 inputs old in the 2 s after a
plant that moved on; told of each schedule move (a plant topic, tried and dropped), it still
withheld 3.6 % of the forces of whole runs on top of the 6-7 % the plant counted stale
(docs/reliability.md; ``test_an_elastic_schedule_looks_late`` shows how).

A delay that lasts longer than the window becomes the new floor: the guard catches stalls,
bursts and backlogs, not a path that is slow for good (that is the supervisor's to trip on).
"""

from __future__ import annotations

import math

#: Window of the fastest delivery, s (the floor is the minimum over the
#: deliveries of the last one or two half windows that had any).
WINDOW_S = 10.0


class InputAge:
    """Excess delay of each input sample over the fastest recent delivery.

    Parameters
    ----------
    limit_s : float
        Largest excess delay of a fresh input, s (a controller: ``control.input_timeout_s``).
    window_s : float
        Window of the fastest delivery, s.

    Attributes
    ----------
    old : int
        Inputs judged older than the limit.
    last_old_ns : int
        Stamp of the newest of them, ns (-1 before the first).
    worst_s : float
        Largest excess delay seen, s.
    """

    def __init__(self, limit_s: float, window_s: float = WINDOW_S) -> None:
        if not (limit_s > 0.0 and window_s > 0.0):
            raise ValueError(f"limit_s and window_s must be > 0 (got {limit_s}, {window_s})")
        self.limit_s = float(limit_s)
        self._half_ns = int(window_s * 0.5e9)
        self._block_end = -1  # arrival (ns) that ends the current half window
        self._cur = math.inf  # minimum offset of the current half window, ns
        self._prev = math.inf  # ... of the one before
        self.old = 0
        self.last_old_ns = -1
        self.worst_s = 0.0

    @property
    def floor_ns(self) -> int | None:
        """The fastest recent offset ``arrival - stamp``, ns (None before the first input):
        the source's epoch on the arrival clock plus the fastest delivery."""
        floor = min(self._cur, self._prev)
        return None if math.isinf(floor) else int(floor)

    def excess_s(self, stamp_ns: int, arrival_ns: int) -> float:
        """The excess delay (s, >= 0) of an input stamped ``stamp_ns`` that arrived at
        ``arrival_ns`` (any monotonic clock, ns); it joins the floor's window."""
        offset = arrival_ns - stamp_ns
        if arrival_ns >= self._block_end:
            # kept across a silence: the floor relates two clocks, which a pause does not move;
            # after a stall the samples it held back are judged against the delivery before it
            self._prev, self._cur = self._cur, math.inf
            self._block_end = arrival_ns + self._half_ns
        self._cur = min(self._cur, offset)
        excess = (offset - min(self._cur, self._prev)) * 1e-9
        self.worst_s = max(self.worst_s, excess)
        return excess

    def fresh(self, stamp_ns: int, arrival_ns: int) -> bool:
        """True if the input is within the limit; else it is counted as old."""
        if self.excess_s(stamp_ns, arrival_ns) <= self.limit_s:
            return True
        self.old += 1
        self.last_old_ns = max(self.last_old_ns, stamp_ns)
        return False


__all__ = ["WINDOW_S", "InputAge"]
