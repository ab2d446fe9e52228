"""A recorded segment's stability verdict: its stage velocities' envelopes
(:mod:`.stability`) judged with the model of the recorded configuration."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray

from dcsms_ros.analysis.series import AXIS_NAMES
from dcsms_ros.analysis.stability import GROWTH_FACTOR, envelope, resolved_factor
from dcsms_ros.core.check import Stability


def judge(bodies: Mapping[str, NDArray[np.floating]], stages: Sequence[str],
          axes: Sequence[str], fs: float, warnings: list[str], where: str,
          model: Stability | None) -> dict[str, Any]:
    """Growing envelopes of the stage velocities (:mod:`.stability`), judged with the model.

    Only segments with a feedback loop closed are judged: an open-loop segment cannot be
    unstable. A growing envelope is a finding of a short record, and a stable loop with slow
    poles makes them too, and so does slow sensor noise: the TEM fit's geophones, extended to
    0.02 Hz, put most of a stage-1 velocity reading's power below 0.2 Hz, where a 60 s segment
    holds a few cycles, and its envelope wanders 3-10x. So, with a stable model, a growth that
    the record's resolved content does not confirm (:func:`.stability.resolved_factor` below
    :data:`.stability.GROWTH_FACTOR`) is listed as ``wander``, not as growing. A segment is
    *unstable* when an envelope grows and the model of the recorded configuration is unstable
    too, or no model is recorded; when the model is stable and the resolved content grows too
    it is reported as *growing* with the model's slowest time constant, and a longer record
    decides.

    Parameters
    ----------
    bodies : mapping of body name to ndarray, shape (K, 3)
        The segment's aligned velocities along x, y, z (m/s), at least ``stages``.
    stages : sequence of str
        The stages judged (``stage1`` ...).
    axes : sequence of str
        The axes judged (``x`` ...).
    fs : float
        Sample rate, Hz.
    warnings : list of str
        A warning for an unstable or growing segment is appended here, prefixed ``where``.
    where : str
        The segment, as the warning names it.
    model : Stability or None
        The model's verdict on the segment's mode in the recorded configuration.

    Returns
    -------
    dict
        ``unstable``, ``growing`` and ``wander`` (lists of ``body``, ``axis``,
        ``rate_per_s``, ``factor``, ``resolved_from_hz``, ``resolved_factor``), ``checked``
        (True) and ``model`` (its verdict, or None).
    """
    growing: list[dict[str, Any]] = []
    wander: list[dict[str, Any]] = []
    stable = model is not None and model.stable
    for s in stages:
        for a in axes:
            x = bodies[s][:, AXIS_NAMES.index(a)]
            env = envelope(x, fs)
            if env is None or not env.growing:
                continue
            g: dict[str, Any] = {"body": s, "axis": a, "rate_per_s": env.rate_per_s,
                                 "factor": env.factor, "resolved_from_hz": 1.0 / env.quarter_s}
            g["resolved_factor"] = resolved_factor(x, fs, env)
            if stable and g["resolved_factor"] < GROWTH_FACTOR:
                wander.append(g)
            else:
                growing.append(g)
    judged = None if model is None else {
        "stable": model.stable, "worst_pole_hz": [model.worst_s_hz.real, model.worst_s_hz.imag],
        "slowest_time_constant_s": (1.0 / (-2.0 * math.pi * model.worst_s_hz.real)
                                    if model.stable and model.worst_s_hz.real < 0 else None)}
    unstable = bool(growing) and (model is None or not model.stable)
    if growing:
        g = max(growing, key=lambda x: float(x["rate_per_s"]))
        grows = (f"the {g['body']} {g['axis']} velocity envelope grows {g['rate_per_s']:.3g} /s "
                 f"(x{g['factor']:.1f} over the segment)")
        if unstable:
            p = None if model is None else model.worst_s_hz
            why = "" if p is None else (f"; the model is unstable too (pole {p.real:+.4f} "
                                        f"{p.imag:+.4f}j Hz)")
            warnings.append(f"{where}: UNSTABLE: {grows}{why}")
        else:
            tau = judged["slowest_time_constant_s"] if judged else None
            slow = f" (slowest time constant {tau:.3g} s)" if tau else ""
            warnings.append(
                f"{where}: growing: {grows}, but the model of the recorded configuration is "
                f"stable{slow}: a slow transient or a lightly damped mode; a longer "
                "record decides")
    return {"unstable": unstable, "growing": growing, "wander": wander, "checked": True,
            "model": judged}


__all__ = ["judge"]
