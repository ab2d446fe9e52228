"""Lockstep barrier: sample k+1 exists only once every due participant answered sample k.

The plant publishes sample k and calls :meth:`LockstepBarrier.begin`; each answer stamped with
sample k's time goes to :meth:`~LockstepBarrier.offer`, which says when the sample is complete.
While waiting, :meth:`~LockstepBarrier.poll` (with the current monotonic time) says when to
publish the sample again (``retry_s`` after the last publication: a lost message is recovered,
the nodes answer a repeated stamp from their cache) and when a participant has missed it
(``timeout_s``): :meth:`~LockstepBarrier.expire` then counts a fault for each missing one (its
answer counts as none) and completes the sample. After ``absent_after`` misses in a row a
participant is *absent*: not waited for until it answers again.

A participant may be due only at some samples (``every``: after sample k with
``(k + 1) % every == 0``), as the instability trip's checkpoints are. A participant may be
asked ``last``: only once every other due participant answered (or missed) the sample
(:meth:`~LockstepBarrier.to_ask`). The trip verdict is: a trip disables the controllers, and
that must not overtake a controller's answer to the checkpoint sample itself. :attr:`hold`
stops the plant before a chosen sample (a mode switch scheduled there happens while nothing
moves).
"""

from __future__ import annotations

import enum
from collections.abc import Collection, Mapping, Sequence
from typing import Any


class Action(enum.Enum):
    """What :meth:`LockstepBarrier.poll` asks the plant to do."""

    NONE = 0
    RETRANSMIT = 1
    TIMEOUT = 2


class LockstepBarrier:
    """The plant's wait for the answers to each sample.

    Parameters
    ----------
    participants : sequence of str
        Who answers (controller ids, ``trip``).
    timeout_s : float
        Wait for an answer before it counts as missed, s (``control.lockstep_timeout_s``).
    retry_s : float
        Republish a sample whose answers are missing after this long, s.
    absent_after : int
        Misses in a row after which a participant is absent.
    first_timeout_s : float
        Timeout of sample 0 (the other nodes hold their first answer until their readers
        matched), s.
    every : mapping of str to int, optional
        Participants due only after sample k with ``(k + 1) % every == 0`` (default 1: every
        sample).
    last : collection of str, optional
        Participants asked only after every other due participant answered or missed the
        sample (:meth:`to_ask`); their timeout starts when they are asked.
    """

    def __init__(self, participants: Sequence[str], timeout_s: float, retry_s: float,
                 absent_after: int, first_timeout_s: float,
                 every: Mapping[str, int] | None = None, last: Collection[str] = ()) -> None:
        self.participants = list(participants)
        self.every = {p: max(1, int((every or {}).get(p, 1))) for p in self.participants}
        self.last = set(last)
        #: ``last`` participants asked about the current sample
        self.asked: set[str] = set()
        self._missed: set[str] = set()  # missed the current sample before ``last`` was asked
        self._due_last = False
        self.timeout_s = timeout_s
        self.retry_s = retry_s
        self.absent_after = absent_after
        self.first_timeout_s = first_timeout_s
        self.absent: set[str] = set()
        self.consec = dict.fromkeys(self.participants, 0)
        self.faults = dict.fromkeys(self.participants, 0)
        self.retransmits = 0
        #: Before which sample index the plant stops (None: no hold).
        self.hold: int | None = None
        self.k = -1
        self.stamp_ns = -1
        self.waiting = False
        self.due: list[str] = []
        self.got: dict[str, Any] = {}
        self._t_sent = self._t_retx = self._t_poll = 0.0

    def due_at(self, k: int) -> list[str]:
        """Participants whose answer to sample ``k`` is waited for (absent ones included)."""
        return [p for p in self.participants if (k + 1) % self.every[p] == 0]

    def may_publish(self, k: int) -> bool:
        """False while :attr:`hold` stops the plant before sample ``k``."""
        return self.hold is None or k < self.hold

    def begin(self, k: int, stamp_ns: int, now: float) -> bool:
        """Sample ``k`` (stamped ``stamp_ns``) was published at ``now`` (s); True if an answer
        must be waited for, False if it is complete at once (nobody due, or all absent)."""
        self.k, self.stamp_ns = k, stamp_ns
        self.got = {}
        self.asked, self._missed = set(), set()
        self.due = self.due_at(k)
        # set operations, not generators: this runs at every sample
        self._due_last = not self.last.isdisjoint(self.due)
        self.waiting = not self.absent.issuperset(self.due)
        self._t_sent = self._t_retx = now
        return self.waiting

    def offer(self, who: str, stamp_ns: int, value: Any = None) -> bool:
        """An answer of ``who`` stamped ``stamp_ns``; True when it completes the sample.

        Any answer brings an absent participant back (it is waited for again from the next
        sample); a repeated, late or unexpected answer is ignored otherwise.
        """
        self.absent.discard(who)
        if (not self.waiting or stamp_ns != self.stamp_ns or who in self.got
                or who not in self.due or who in self._missed):
            return False
        self.got[who] = value
        self.consec[who] = 0
        # nothing is missing only once every due participant answered, is absent or missed
        # it: fewer of those than due participants need no look at each one
        if (len(self.got) + len(self.absent) + len(self._missed) >= len(self.due)
                and not self.missing()):
            self.waiting = False
            return True
        return False

    def missing(self) -> list[str]:
        """Due participants that have not answered the current sample and are not absent (nor
        given up for it)."""
        return [p for p in self.due
                if p not in self.got and p not in self.absent and p not in self._missed]

    def to_ask(self) -> list[str]:
        """The ``last`` participants to ask about the current sample now: each once, when every
        other due participant has answered, missed it or is absent."""
        if not self._due_last or not self.waiting:
            return []
        missing = self.missing()
        if any(p not in self.last for p in missing):
            return []
        new = [p for p in missing if p not in self.asked]
        self.asked.update(new)
        return new

    def poll(self, now: float) -> Action:
        """What to do at ``now`` (s) while waiting: nothing, republish, or give up."""
        if not self.waiting:
            return Action.NONE
        self._t_poll = now
        limit = self.timeout_s if self.k > 0 else self.first_timeout_s
        if now - self._t_sent > limit:
            return Action.TIMEOUT
        if now - self._t_retx > self.retry_s:
            self._t_retx = now
            self.retransmits += 1
            return Action.RETRANSMIT
        return Action.NONE

    def next_deadline(self, now: float) -> float:
        """Seconds from ``now`` until :meth:`poll` has something to do (0 if overdue)."""
        limit = self.timeout_s if self.k > 0 else self.first_timeout_s
        due = min(self._t_sent + limit, self._t_retx + self.retry_s)
        return max(due - now, 0.0) + 1e-4  # poll() needs the deadline passed

    def expire(self) -> tuple[list[str], list[str]]:
        """Count a fault for every missing participant and complete the sample; while a
        ``last`` participant has not been asked yet, only the others miss it: the sample stays
        open, with a new timeout, for the ``last`` ones (:meth:`to_ask` now returns them).

        Returns
        -------
        missing : list of str
            Who missed this sample.
        absent : list of str
            Who became absent with this miss.
        """
        missing = self.missing()
        later = [p for p in missing if p in self.last and p not in self.asked]
        if later and len(later) < len(missing):
            missing = [p for p in missing if p not in later]
            self._missed.update(missing)
            self._t_sent = self._t_retx = self._t_poll
        else:
            self.waiting = False
        newly = []
        for p in missing:
            self.faults[p] += 1
            self.consec[p] += 1
            if self.consec[p] >= self.absent_after:
                self.absent.add(p)
                newly.append(p)
        return missing, newly

    def state(self, who: str) -> str:
        """``absent`` or ``ok``."""
        return "absent" if who in self.absent else "ok"


__all__ = ["Action", "LockstepBarrier"]
