"""A writer's view of its DDS readers (protocols/matched.py): the cached matched count and the
history held for the first reader outside the process."""

from __future__ import annotations

import pytest

from dcsms_ros.protocols.matched import (
    LANE_MATCH_REFRESH_NS,
    MATCH_REFRESH_NS,
    HeldHistory,
    MatchCount,
)


@pytest.mark.parametrize("refresh", [None, LANE_MATCH_REFRESH_NS])
def test_match_count_asks_again_only_after_the_refresh_interval(refresh: int | None) -> None:
    """The count is asked at the first call, kept for the refresh interval (MATCH_REFRESH_NS
    unless given), and asked again at the first call after it: a reader matched at t is seen
    from t + the interval at the latest."""
    now = [5_000]
    readers = [2]
    asked = []

    def ask() -> int:
        asked.append(now[0])
        return readers[0]

    count = (MatchCount(ask, clock=lambda: now[0]) if refresh is None else
             MatchCount(ask, clock=lambda: now[0], refresh_ns=refresh))
    every = MATCH_REFRESH_NS if refresh is None else refresh
    assert count() == 2 and asked == [5_000]
    readers[0] = 3  # a remote reader matches
    now[0] += every - 1
    assert count() == 2 and len(asked) == 1
    now[0] += 1
    assert count() == 3 and asked == [5_000, 5_000 + every]
    readers[0] = 2  # ... and leaves
    now[0] += 2 * every
    assert count() == 2 and len(asked) == 3


@pytest.mark.parametrize("published, depth", [(3, 5), (12, 5)])
def test_held_history_keeps_the_newest_depth_messages_until_released(published: int,
                                                                     depth: int) -> None:
    """What a transient-local writer published in the process only: the newest ``depth``,
    oldest first, once; nothing is released twice."""
    h = HeldHistory(depth)
    for k in range(published):
        h.hold(b"%d" % k)
    assert len(h) == min(published, depth)
    assert h.release() == [b"%d" % k for k in range(max(published - depth, 0), published)]
    assert h.release() == [] and len(h) == 0
