"""Whole-sample delay lines of controller outputs."""

from __future__ import annotations

import numpy as np
import pytest

from dcsms_ros.core.delayline import DelayLines
from dcsms_ros.errors import ConfigError


def test_each_line_returns_the_output_d_samples_back():
    lines = DelayLines({"fb_stage1": 3, "fb_stage2": 0}, {"fb_stage1", "fb_stage2"}, 2)
    got = [lines.shift("fb_stage1", np.array([k, -k], float)) for k in range(1, 8)]
    np.testing.assert_array_equal([g[0] for g in got], [0, 0, 0, 1, 2, 3, 4])
    w = np.array([5.0, 6.0])
    assert lines.shift("fb_stage2", w) is w
    assert lines.shift("ff_stage1", w) is w


@pytest.mark.parametrize(("delays", "msg"), [({"fb_stage9": 1}, "unknown controller"),
                                             ({"fb_stage1": -1}, "whole number"),
                                             ({"fb_stage1": 1.5}, "whole number")])
def test_bad_delays_are_refused(delays, msg):
    with pytest.raises(ConfigError, match=msg):
        DelayLines(delays, {"fb_stage1"}, 1)
