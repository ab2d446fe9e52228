"""Write a batch :class:`~dcsms_ros.core.engine.SimResult` as the bag a graph recording gives.

Same topics and message types as the live graph (docs/ARCHITECTURE.md, ROS graph table):

==============================  ==========================  ===================================
topic                           type                        content
==============================  ==========================  ===================================
/dcsms/sensors/raw              sensor_msgs/JointState      ``name`` = channels, ``velocity``
/dcsms/truth/<body>             geometry_msgs/TwistStamped  true twist, frame_id = body
/dcsms/velocity/<body>          geometry_msgs/TwistStamped  decoupled twist, frame_id = body
/dcsms/force/<controller>       geometry_msgs/WrenchStamped command, frame_id = its stage
/dcsms/force/excitation         geometry_msgs/WrenchStamped excitation (if any), frame_id = stage
/dcsms/actuators/applied        sensor_msgs/JointState      ``name`` = actuators, ``effort`` N
/dcsms/mode                     std_msgs/String             label at every switch (latched QoS)
/dcsms/supervisor/state         std_msgs/String             every supervisor transition (latched)
/dcsms/config                   std_msgs/String             flat parameters as YAML (latched)
/clock (only if asked)          rosgraph_msgs/Clock         sim time
==============================  ==========================  ===================================

Bag time and header stamp of sample k are both its sim time ``k * dt`` in ns (plus ``t0_ns``).
``/dcsms/supervisor/state`` holds one ``Transition.label`` per entry of ``res.supervision`` at
its sample's time, and is there only when the run has a transition. ``/clock`` is left out by
default because the recorder leaves it out by default, so a batch bag and a graph recording
hold the same topics. ``/diagnostics`` is not synthesised (the
batch run's fault counters are returned by :func:`export_result` instead). A 1-DOF run fills
only the z component (index 2) of each twist and wrench.

Messages are encoded with the numpy codecs of :mod:`dcsms_ros.cdr` in blocks of
``block`` samples per topic (bounded memory on long runs); within a block, topics are written
one after the other, which MCAP and SQLite both index by time.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from dcsms_ros import cdr
from dcsms_ros.analysis.bagio import LATCHED_QOS, BagWriter, open_bag
from dcsms_ros.analysis.reader import CONFIG_TOPIC, config_to_yaml
from dcsms_ros.core import topics
from dcsms_ros.core.modes import ControllerId
from dcsms_ros.core.simresult import SimResult
from dcsms_ros.errors import BagError

#: Samples per topic encoded at once (~100 B each: a few MB per topic and block).
BLOCK = 20_000


def to_six(values: NDArray[np.float64], dof: int) -> NDArray[np.float64]:
    """(K, dof) -> (K, 6): a 1-DOF series goes into z (index 2), the rest is zero."""
    v = np.asarray(values, dtype=np.float64)
    if dof == 6:
        return v.reshape(-1, 6)
    out = np.zeros((v.shape[0], 6))
    out[:, 2] = v.reshape(v.shape[0], -1)[:, 0]
    return out


def sample_times_ns(res: SimResult, t0_ns: int = 0) -> NDArray[np.int64]:
    """Sample times ``t0_ns + k * dt`` in integer ns, shape (K,) (exact for 1 ns-multiple dt)."""
    dt_ns = int(round(res.cfg.plant.dt * 1e9))
    return t0_ns + np.arange(res.t.size, dtype=np.int64) * dt_ns


def _force_frame(controller: str) -> str:
    """The stage a controller pushes: FB on stage i -> ``stage<i>``, FF -> ``stage1``."""
    return ControllerId.parse(controller).frame


def _excited_stage(res: SimResult) -> int | None:
    """Index of the stage the run's excitation pushes (one stage per run), or None."""
    if res.excitation is None:
        return None
    hit = np.flatnonzero(np.any(res.excitation != 0.0, axis=(0, 2)))
    if hit.size > 1:
        raise BagError("the excitation pushes several stages; /dcsms/force/excitation holds "
                       "one (record one stage per run)")
    return int(hit[0]) if hit.size else 0


def export_result(res: SimResult, writer: BagWriter, t0_ns: int = 0, clock: bool = False,
                  block: int = BLOCK,
                  progress: Callable[[float], None] | None = None) -> dict[str, int]:
    """Write every topic of ``res`` into an open bag.

    Parameters
    ----------
    res : SimResult
        A batch run (:func:`dcsms_ros.core.engine.simulate`).
    writer : BagWriter
        An open, empty bag.
    t0_ns : int
        Bag time and stamp of sample 0, ns.
    clock : bool
        Also write ``/clock`` (one message per sample).
    block : int
        Samples per topic encoded at once.
    progress : callable, optional
        Called with the fraction written (0..1) after every block.

    Returns
    -------
    dict of str to int
        Messages written per topic.
    """
    cfg = res.cfg
    dof = cfg.plant.dof
    bodies = topics.body_names(cfg.plant.num_stages)
    t_ns = sample_times_ns(res, t0_ns)
    k_total = t_ns.size
    writer.add_topic(CONFIG_TOPIC, cdr.STRING, LATCHED_QOS)
    writer.add_topic(topics.MODE, cdr.STRING, LATCHED_QOS)
    if res.supervision:
        writer.add_topic(topics.SUPERVISOR_STATE, cdr.STRING, LATCHED_QOS)
    writer.add_topic(topics.SENSORS_RAW, cdr.JOINT_STATE)
    for b in bodies:
        writer.add_topic(topics.truth_topic(b), cdr.TWIST_STAMPED)
        writer.add_topic(topics.velocity_topic(b), cdr.TWIST_STAMPED)
    for cid in res.wrench:
        writer.add_topic(topics.force_topic(cid), cdr.WRENCH_STAMPED)
    exc_stage = _excited_stage(res)
    if exc_stage is not None:
        writer.add_topic(topics.EXCITATION, cdr.WRENCH_STAMPED)
    writer.add_topic(topics.ACTUATORS_APPLIED, cdr.JOINT_STATE)
    if clock:
        writer.add_topic(topics.CLOCK, cdr.CLOCK)
    t_first = int(t_ns[0]) if k_total else t0_ns
    writer.write(CONFIG_TOPIC, t_first, cdr.encode_string(config_to_yaml(cfg)))
    for k, label in res.mode:
        if k < k_total:
            writer.write(topics.MODE, int(t_ns[k]), cdr.encode_string(label))
    for tr in res.supervision:
        if tr.sample < k_total:
            writer.write(topics.SUPERVISOR_STATE, int(t_ns[tr.sample]),
                         cdr.encode_string(tr.label))
    for start in range(0, k_total, block):
        sl = slice(start, min(start + block, k_total))
        t = t_ns[sl]
        writer.write_many(topics.SENSORS_RAW, t, cdr.encode_joint_state(
            t, "", res.channel_names, velocity=res.raw[sl]))
        for i, b in enumerate(bodies):
            writer.write_many(topics.truth_topic(b), t, cdr.encode_stamped(
                cdr.TWIST_STAMPED, t, b, to_six(res.truth[sl, i], dof)))
            writer.write_many(topics.velocity_topic(b), t, cdr.encode_stamped(
                cdr.TWIST_STAMPED, t, b, to_six(res.velocity[sl, i], dof)))
        for cid, w in res.wrench.items():
            writer.write_many(topics.force_topic(cid), t, cdr.encode_stamped(
                cdr.WRENCH_STAMPED, t, _force_frame(cid), to_six(w[sl], dof)))
        if exc_stage is not None and res.excitation is not None:
            writer.write_many(topics.EXCITATION, t, cdr.encode_stamped(
                cdr.WRENCH_STAMPED, t, f"stage{exc_stage + 1}",
                to_six(res.excitation[sl, exc_stage], dof)))
        writer.write_many(topics.ACTUATORS_APPLIED, t, cdr.encode_joint_state(
            t, "", res.actuator_names, effort=res.applied[sl]))
        if clock:
            writer.write_many(topics.CLOCK, t, cdr.encode_clock(t))
        if progress is not None:
            progress(sl.stop / k_total)
    return dict(writer.counts)


def write_result_bag(res: SimResult, out: str | Path, storage: str = "mcap",
                     clock: bool = False,
                     progress: Callable[[float], None] | None = None) -> dict[str, int]:
    """Create bag ``out`` (must not exist) holding ``res``; see :func:`export_result`.

    Raises
    ------
    BagError
        ``out`` exists or cannot be written (the bag is then not left behind).
    """
    with open_bag(out, storage) as w:
        return export_result(res, w, clock=clock, progress=progress)


__all__ = ["BLOCK", "export_result", "sample_times_ns", "to_six", "write_result_bag"]
