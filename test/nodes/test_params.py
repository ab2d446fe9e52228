"""Parameters through the standard services: descriptors, rejection with a reason, live retune."""

from __future__ import annotations

import math

import numpy as np
import rclpy
from node_helpers import executor_for, overrides, spin_until
from rcl_interfaces.srv import DescribeParameters
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient

from dcsms_ros.nodes.feedback_controller import FeedbackControllerNode


def _set(ex, client, params):
    fut = client.set_parameters(params)
    assert spin_until(ex, fut.done, 10.0)
    return fut.result().results


def test_descriptors_and_rejections_with_reasons(ctx, cfg):
    """Ranges/units are described; bad values are rejected with the reason and change nothing."""
    fb = FeedbackControllerNode(context=ctx, parameter_overrides=overrides(cfg, stage=1))
    tool = rclpy.create_node("param_tool", context=ctx)
    client = AsyncParameterClient(tool, "/dcsms/fb_stage1")
    ex = executor_for(ctx, fb, tool)
    assert spin_until(ex, client.services_are_ready, 10.0)
    fut = client.describe_parameters(["feedback.stage1.lowpass_hz", "stage1.mass"])
    assert spin_until(ex, fut.done, 10.0)
    lp, mass = fut.result().descriptors
    assert "[Hz]" in lp.description and lp.floating_point_range[0].to_value == 1e4
    assert mass.read_only and "[kg]" in mass.description
    assert isinstance(fut.result(), DescribeParameters.Response)
    before = fb.loop
    cases = {
        "feedback.stage1.lowpass_hz": -1.0,  # below the descriptor range (rclpy's check)
        "feedback.stage1.notch_q": 0.0,  # open lower bound: config_from_flat's check
        "feedback.stage1.highpass_hz": math.nan,
        "feedback.stage1.gain": [0.0, 0.0, 1e4],  # wrong length
        "stage1.mass": 10.0,  # structure is read-only at run time
    }
    for name, value in cases.items():
        (res,) = _set(ex, client, [Parameter(name, value=value)])
        assert not res.successful, name
        assert res.reason, name
        print(f"{name}={value!r}: rejected: {res.reason}")
    assert fb.loop is before  # nothing was rebuilt
    assert fb.params.flat["feedback.stage1.notch_q"] == 5.0
    ex.shutdown()


def test_gain_change_retunes_the_running_loop(ctx, cfg):
    """A valid gain change is accepted and applied; the fade state is kept."""
    # lockstep: enabled starts at full gain (real time fades in from zero)
    fb = FeedbackControllerNode(context=ctx, parameter_overrides=overrides(
        cfg, stage=1, enabled=True, schedule="lockstep"))
    tool = rclpy.create_node("param_tool", context=ctx)
    client = AsyncParameterClient(tool, "/dcsms/fb_stage1")
    ex = executor_for(ctx, fb, tool)
    assert spin_until(ex, client.services_are_ready, 10.0)
    v = np.array([1e-4])
    w1 = fb.loop.step(v)
    gain = [0.0, 0.0, 3.0e4, 0.0, 0.0, 0.0]
    (res,) = _set(ex, client, [Parameter("feedback.stage1.gain", value=gain)])
    assert res.successful, res.reason
    assert fb.params.cfg.feedback[0].gain == tuple(gain)
    assert fb.loop.enabled and fb.loop.fader.value == 1.0
    # twice the gain, same filter state carried over: the first output doubles the old one's
    # zero-state response, so it is clearly larger than before
    w2 = fb.loop.step(v)
    assert abs(w2[0]) > abs(w1[0])
    ex.shutdown()
