"""What a writer knows of its DDS readers: the matched-reader count, asked at most every
:data:`MATCH_REFRESH_NS` (an rmw call per publication was 3.6 % of the composed lockstep step),
and the history a keep-last writer that published in its process only holds for the first
reader outside it (:mod:`dcsms_ros.ros.intraprocess`). Also the lane inputs' count of a
reader's matched writers (:mod:`dcsms_ros.ros.laneinput`). No ROS here: unit-tested with a
fake clock (test/protocols/test_matched.py).
"""

from __future__ import annotations

import time
from collections import deque
from collections.abc import Callable

#: How long (ns) a composed publisher trusts its DDS writer's matched-reader count. A reader
#: that matched within it misses nothing of a transient-local topic (the held history), and of
#: a volatile one at most that millisecond's messages, as if DDS had matched it 1 ms later.
MATCH_REFRESH_NS = 1_000_000
#: The same for one process per node, whose per-sample messages to this host's nodes go on
#: lanes (:mod:`dcsms_ros.ros.hostlane`): there a DDS count only tells of a peer without a lane
#: (another host, a tool) coming or going, and a lane's own hello or bye is acted on at once.
#: Asked every millisecond it was an rcl call every other sample (2 kHz) in each writer and
#: lane reader: 1.2 calls a sample in a controller, 1.7 in the plant, ~2-3 us each on a thread
#: woken every 500 us (docs/performance.md, "Fewer calls a sample").
LANE_MATCH_REFRESH_NS = 10_000_000


class MatchCount:
    """A DDS writer's matched-reader count, asked at most every ``refresh_ns``.

    Parameters
    ----------
    ask : callable
        ``ask()`` -> int, the count (the publisher handle's ``get_subscription_count``).
    clock : callable
        ``clock()`` -> int ns (monotonic).
    refresh_ns : int
        How long a count is kept, ns.
    """

    def __init__(self, ask: Callable[[], int], clock: Callable[[], int] = time.monotonic_ns,
                 refresh_ns: int = MATCH_REFRESH_NS) -> None:
        self._ask, self._clock = ask, clock
        self.refresh_ns = int(refresh_ns)
        self._n = 0
        self._due = -1

    def __call__(self) -> int:
        """The count, at most :attr:`refresh_ns` old."""
        now = self._clock()
        if now >= self._due:
            self._n = int(self._ask())
            self._due = now + self.refresh_ns
        return self._n


class HeldHistory:
    """The newest ``depth`` messages a keep-last writer did not publish on DDS (no reader
    outside the process was matched), so that the first remote reader still gets the history
    a transient-local writer promises: :meth:`release` them before the next DDS publication.
    Messages that went to DDS are in the DDS writer's own history and are not held again.

    Parameters
    ----------
    depth : int
        The writer's history depth (messages).
    """

    def __init__(self, depth: int) -> None:
        self._held: deque[bytes] = deque(maxlen=max(int(depth), 1))

    def __len__(self) -> int:
        return len(self._held)

    def hold(self, data: bytes) -> None:
        """Keep ``data`` (published in the process only); the oldest goes beyond ``depth``."""
        self._held.append(data)

    def release(self) -> list[bytes]:
        """The held messages, oldest first, and forget them."""
        out = list(self._held)
        self._held.clear()
        return out


__all__ = ["LANE_MATCH_REFRESH_NS", "MATCH_REFRESH_NS", "HeldHistory", "MatchCount"]
