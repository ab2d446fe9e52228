"""A stream held as arrays: blocks in, the rows a one-by-one queue would hold out."""

from __future__ import annotations

import numpy as np
import pytest

from dcsms_ros.protocols.stampedrows import StampedRows


def _one_by_one(stamps: list[int], floor: int = -1) -> list[int]:
    """The stamps a per-message queue keeps: each above every earlier one and the floor."""
    kept, newest = [], floor
    for s in stamps:
        if s > newest:
            kept.append(s)
            newest = s
    return kept


@pytest.mark.parametrize("split", [1, 3, 7, 50])
def test_blocks_keep_what_messages_one_by_one_keep(split: int) -> None:
    rng = np.random.default_rng(split)
    stamps = np.cumsum(rng.integers(-2, 4, 50)) + 10  # repeats and older stamps among them
    rows = stamps[:, None] * np.array([1.0, -1.0])
    st = StampedRows(2)
    for j in range(0, stamps.size, split):
        st.extend(stamps[j:j + split], rows[j:j + split], floor=5)
    got, v = st.take(10 ** 9)
    want = _one_by_one(stamps.tolist(), floor=5)
    np.testing.assert_array_equal(got, want)
    np.testing.assert_array_equal(v[:, 0], want)
    assert st.newest == max(want) and len(st) == 0


def test_take_splits_at_a_stamp_and_refuses_older_ones_afterwards() -> None:
    st = StampedRows(1)
    st.extend([10, 20, 30, 40], [[1.0], [2.0], [3.0], [4.0]])
    s, _ = st.take(30, inclusive=False)
    assert s.tolist() == [10, 20] and len(st) == 2
    s, _ = st.take(30)
    assert s.tolist() == [30] and len(st) == 1
    st.extend([35, 50], [[9.0], [5.0]])  # 35 is older than the newest accepted (40)
    assert st.take(100)[0].tolist() == [40, 50]
    st.clear()
    st.extend([45], [[1.0]])
    assert len(st) == 0 and st.newest == 50


def test_take_at_fills_missing_samples_with_zero_and_consumes_through_the_last() -> None:
    st = StampedRows(2)
    st.extend([1, 3, 4, 6, 9], [[1, 1], [3, 3], [4, 4], [6, 6], [9, 9]])
    out = st.take_at(np.array([2, 3, 6], dtype=np.int64))
    np.testing.assert_array_equal(out, [[0, 0], [3, 3], [6, 6]])
    assert st.take(100)[0].tolist() == [9]
    assert st.take_at(np.zeros(0, dtype=np.int64)).shape == (0, 2)
