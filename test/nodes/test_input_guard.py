"""The plausibility guard of a node's inputs: every element finite and within the limit,
whatever the length (one dof takes its own comparison, more take the iterator)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest
import rclpy

from dcsms_ros.ros.guard import MAX_VELOCITY_MPS, InputGuard

NAN, INF = math.nan, math.inf


@pytest.mark.parametrize(("x", "ok"), [
    ((0.0,), True), ((MAX_VELOCITY_MPS,), True), ((-MAX_VELOCITY_MPS,), True),
    ((float(np.nextafter(MAX_VELOCITY_MPS, INF)),), False), ((NAN,), False), ((INF,), False),
    ((-INF,), False), ((1e-6, -2.0, 3.0), True), ((1e-6, NAN, 3.0), False),
    ((1.0, 2.0, -11.0, 0.0, 0.0, 0.0), False), ((), True),
    (np.array([0.5]), True), (np.array([NAN]), False), (np.array([1.0, 2.0, 20.0]), False),
])
def test_plausible_is_every_element_finite_and_within_the_limit(ctx: Any, x: Any,
                                                                ok: bool) -> None:
    node = rclpy.create_node("guard_unit", context=ctx)
    try:
        guard = InputGuard(node, "velocity", MAX_VELOCITY_MPS)
        assert guard.plausible(x) is ok
        got = guard.clean_floats(tuple(np.asarray(x, dtype=float).tolist()), NAN)
        if ok:
            assert got == tuple(np.asarray(x, dtype=float).tolist())
            assert guard.rejected == 0
        else:
            assert len(got) == len(x) and all(math.isnan(v) for v in got)
            assert guard.rejected == 1
    finally:
        node.destroy_node()
