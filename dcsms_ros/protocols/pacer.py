"""Real-time pacing of the plant: deadlines, overruns, and held inputs that go stale.

Sample k is due at ``t0 + k / rate``, ``t0`` the first time the loop asks what is due (or an
explicit :meth:`Pacer.start`): a schedule started in another thread than the one that keeps it
was ~3 ms old when the loop first ran, and its first 7-14 samples counted late in every composed
run (docs/performance.md). A sample computed once the next one is due already
(the plant woke more than a period late and catches up) is *late*: it reaches the controllers
after its deadline, and a keep-last-1 reader then answers only the newest of the burst. A plant
that fell more than ``max_burst`` samples behind does not catch up in a burst: the backlog is
dropped (counted as overruns) and the schedule moves on from now. Of those missed deadlines,
the ones the loop's own late wake-up missed while nothing of its process ran are counted apart
(:attr:`Pacer.woke_late`): the loop slept to a deadline and got the CPU after it, so a loop
with no work at all would have missed them too (on this package's virtual machine, mostly
whole-machine pauses of ~3 ms; docs/performance.md, "Who makes composed samples late"); those
that a pause while the loop worked pushed back are counted apart too (:attr:`Pacer.paused`).
A delay while another thread of the process ran, holding the GIL, is the process's own and is
not counted in either (the loop tells which, :class:`dcsms_ros.ros.pausemeter.PauseMeter`).
Inputs (force commands) are *held*: the newest value of each is used until it is older than
``timeout_s``, then it counts as zero (stale).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

#: At most this many samples are computed at once to catch up.
MAX_BURST = 20


class Pacer:
    """Deadlines of a loop at ``rate_hz`` (Hz) started at :meth:`start`."""

    def __init__(self, rate_hz: float, max_burst: int = MAX_BURST) -> None:
        self.rate = float(rate_hz)
        self.max_burst = max_burst
        self.t0 = 0.0
        #: whether the schedule has started (:meth:`start`, or the first :meth:`due`)
        self.started = False
        #: samples dropped from a backlog of more than ``max_burst``
        self.overruns = 0
        #: samples computed in a catch-up burst, after the next sample was due
        self.late = 0
        #: of :attr:`late` and :attr:`overruns`, those that were not yet missed when the loop
        #: asked to wake and passed while nothing of its process ran (:meth:`due`'s
        #: ``woke_late_s``)
        self.woke_late = 0
        #: of :attr:`late` and :attr:`overruns`, those that the loop would have met but for
        #: the time it worked while nothing of its process ran (:meth:`due`'s ``paused_s``)
        self.paused = 0

    def start(self, now: float) -> None:
        """Sample 0 is due at ``now`` (s)."""
        self.t0 = now
        self.started = True

    def due(self, now: float, k: int, woke_late_s: float = 0.0, paused_s: float = 0.0) -> int:
        """How many samples to compute at ``now`` (s) when ``k`` are done; the first call of a
        pacer not started makes sample ``k`` due at ``now``. ``woke_late_s`` (s): how long
        after the time it asked to wake the loop got to run while nothing of its process ran
        (0: it did not sleep, or woke in time); the missed deadlines in that time before now
        count in :attr:`woke_late`. ``paused_s`` (s): how long, since the last samples it
        computed, the loop worked while nothing of its process ran; the missed deadlines in
        that time before the late wake-up count in :attr:`paused` (a pause pushes back
        everything after it, so without it the loop would have been that much earlier)."""
        if not self.started:
            self.start(now - k / self.rate)
        due = int((now - self.t0) * self.rate) + 1 - k
        if due > 1 and (woke_late_s > 0.0 or paused_s > 0.0):
            asked = max(int((now - woke_late_s - self.t0) * self.rate) + 1 - k, 1)
            self.woke_late += due - asked
            if asked > 1:
                unpaused = int((now - woke_late_s - paused_s - self.t0) * self.rate) + 1 - k
                self.paused += asked - max(unpaused, 1)
        if due > self.max_burst:
            # too far behind to catch up without a burst: drop the backlog, count it
            self.overruns += due - 1
            self.t0 += (due - 1) / self.rate
            due = 1
        elif due > 1:
            self.late += due - 1  # all but the newest of the burst missed their deadline
        return max(due, 0)

    def wait_s(self, now: float, k: int) -> float:
        """Seconds from ``now`` until sample ``k`` is due (negative: late)."""
        return self.t0 + k / self.rate - now


class HeldInputs:
    """The newest value of each named input and the time it counts from (its arrival, or the
    plant's choice: its sample's publication); stale ``timeout_s`` after that.

    Parameters
    ----------
    names : sequence of str
        Inputs (controller ids).
    timeout_s : float
        Age at which a held value is stale and counts as ``zero``, s.
    zero : Any
        The value of a stale or never-seen input.
    """

    def __init__(self, names: Sequence[str], timeout_s: float, zero: Any) -> None:
        self.names = list(names)
        self.timeout_s = timeout_s
        self.zero = zero
        self._held: dict[str, tuple[Any, float]] = {}
        self.stale = dict.fromkeys(self.names, True)
        self.stale_events = dict.fromkeys(self.names, 0)
        #: samples taken with this input stale after it first arrived (before: start-up)
        self.stale_samples = dict.fromkeys(self.names, 0)
        #: samples taken with this input fresh but counting from before ``due`` (:meth:`take`):
        #: the loop ran with more delay than its nominal one
        self.delayed_samples = dict.fromkeys(self.names, 0)

    def put(self, name: str, value: Any, t: float) -> None:
        """Input ``name`` got ``value``, valid from ``t`` (s); an older one than the value held
        (a reordered message) is ignored."""
        if t >= self._held.get(name, (None, -math.inf))[1]:
            self._held[name] = (value, t)

    def arrived(self, name: str) -> float:
        """The time the held value of ``name`` counts from (s; the plant's: the publication of
        the sample its force answers), -inf if never."""
        return self._held.get(name, (None, -math.inf))[1]

    def take(self, now: float, due: float = -math.inf) -> tuple[dict[str, Any], list[str]]:
        """The values to use at ``now`` (s), and the inputs that have just gone stale.
        ``due`` (s): the time the newest value that could be held by now counts from (the
        plant's: the publication of the previous sample); a fresh value that counts from
        before it (its answer was skipped or came late) is counted in
        :attr:`delayed_samples`."""
        out: dict[str, Any] = {}
        newly = []
        for n in self.names:
            v, t = self._held.get(n, (self.zero, -math.inf))
            stale = now - t > self.timeout_s
            if stale and t > -math.inf:
                self.stale_samples[n] += 1
            elif not stale and t < due:
                self.delayed_samples[n] += 1
            if stale and not self.stale[n]:
                self.stale_events[n] += 1
                newly.append(n)
            self.stale[n] = stale
            out[n] = self.zero if stale else v
        return out, newly


class Publications:
    """When each of the last ``size`` samples went out, and the time an answer to one counts
    from.

    An answer counts from its sample's publication, so its age is the delay it adds to the
    loop, and never from later than that sample would have gone out on the newest one's
    schedule. The two agree while the plant keeps its schedule. They part when samples go out
    closer together than their period: a catch-up burst (:class:`Pacer`) publishes up to
    ``MAX_BURST`` at once, and a thread preempted inside one records its later samples'
    publications milliseconds after the burst woke. Aged from publication alone, an answer to
    a sample 40 periods (20 ms, twice the timeout) older than the newest was then applied, and
    the simulated stages saw a 20 ms loop delay (``test_force_age`` in CI, stop 65; the seeded
    model in ``test/protocols/test_pacer.py``).

    Parameters
    ----------
    rate_hz : float
        Sample rate, Hz.
    size : int
        Samples remembered at least; an answer to an older one counts as never valid (256:
        128 ms at 2 kHz, 13x the default 10 ms timeout). :meth:`cover` keeps more for a
        longer timeout.
    """

    #: The time an answer to a sample too old to remember counts from, ns.
    NEVER_NS = -(2**62)

    def __init__(self, rate_hz: float, size: int = 256) -> None:
        self.period_ns = round(1e9 / rate_hz)
        self.size = size
        self._t = [0] * size
        #: index of the newest sample published (-1 before the first)
        self.newest = -1

    def cover(self, span_s: float) -> None:
        """Remember the samples of the last ``span_s`` (an input timeout, s) and a catch-up
        burst more, keeping what is remembered: an answer younger than the timeout is then
        never counted as forgotten (with 256 samples, a 0.5 s timeout at 2 kHz was cut to
        128 ms). Call it with the node's other state (not beside :meth:`put`)."""
        need = math.ceil(span_s * 1e9 / self.period_ns) + MAX_BURST + 1
        if need <= self.size:
            return
        t = [0] * need
        for k in range(max(self.newest - self.size + 1, 0), self.newest + 1):
            t[k % need] = self._t[k % self.size]
        self._t, self.size = t, need

    def put(self, k: int, t_ns: int) -> None:
        """Sample ``k`` went out at ``t_ns`` (monotonic ns)."""
        self._t[k % self.size] = t_ns
        self.newest = k

    def at_ns(self, k: int) -> int | None:
        """Monotonic ns of sample ``k``'s publication; None if not published or forgotten."""
        return self._t[k % self.size] if 0 <= self.newest - k < self.size and k >= 0 else None

    def answered(self, k: int, now_ns: int) -> tuple[int | None, int]:
        """An answer to sample ``k`` arrived at ``now_ns``: its sample's publication (None if
        not published or forgotten) and the monotonic ns the answer counts from, the earlier
        of that publication and the newest's less the periods between them (``now_ns`` for a
        sample not published yet, not an answer of this loop; :attr:`NEVER_NS` for one
        forgotten). One call a force, three a sample."""
        age = self.newest - k
        if age < 0:
            return None, now_ns
        if age >= self.size or k < 0:
            return None, self.NEVER_NS
        t = self._t
        t_k = t[k % self.size]
        return t_k, min(t_k, t[self.newest % self.size] - age * self.period_ns)


class Watchdog:
    """A controller's input watchdog: stale when nothing arrived for ``timeout_s``.

    Attributes
    ----------
    stale : bool
    stale_events : int
        Times it went stale.
    """

    def __init__(self, timeout_s: float) -> None:
        self.timeout_s = timeout_s
        self.last: float | None = None
        self.stale = False
        self.stale_events = 0
        self._repeat_at = 0.0

    @property
    def repeat_s(self) -> float:
        """Interval of the repeated zero force while stale, s (a quarter timeout, >= 1 ms)."""
        return max(self.timeout_s / 4.0, 1e-3)

    def feed(self, now: float) -> bool:
        """An input arrived at ``now`` (s); True if it ends a stale period."""
        self.last = now
        back, self.stale = self.stale, False
        return back

    def check(self, now: float) -> bool | None:
        """At ``now`` (s): True when the input has just gone stale, False when the repeated
        zero force is due again (every :attr:`repeat_s` while stale), None otherwise (fresh,
        no input yet, or a repeat not due). A composed process's driver calls it at every
        wake-up of any node: answering False each time made a stale controller publish ~24,000
        zero forces a second (measured, docs/performance.md)."""
        if self.last is None or now - self.last <= self.timeout_s:
            return None
        if not self.stale:
            self.stale = True
            self.stale_events += 1
            newly = True
        elif now < self._repeat_at:
            return None
        else:
            newly = False
        self._repeat_at = now + self.repeat_s
        return newly

    def wait_s(self, now: float) -> float | None:
        """Seconds until the next :meth:`check` has something to say."""
        if self.last is None:
            return None
        left = self.last + self.timeout_s - now
        if left > 0.0:
            return left
        return max(self._repeat_at - now, 0.0) if self.stale else 0.0


__all__ = ["MAX_BURST", "HeldInputs", "Pacer", "Publications", "Watchdog"]
