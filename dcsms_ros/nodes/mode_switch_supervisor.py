"""mode_switch's watch over the table: the stage, ground and force streams it judges.

Supervisor (``supervisor.enabled``, the default; :mod:`dcsms_ros.core.supervisor`, fed by
:class:`~dcsms_ros.protocols.superfeed.SupervisedFeed` from the stage and ground velocities
and the applied forces) or, without it, the plain trip (:class:`~dcsms_ros.core.trip.
TripChecker` fed by :class:`~dcsms_ros.protocols.tripfeed.TripFeed` from the stage velocities).

The stage velocities (and, with the supervisor on, the ground velocity and the applied forces)
are subscribed detached: no executor or hot-loop wake-up per sample; :meth:`TableWatch.drain`
empties the queues in blocks into the instability trip
(:class:`~dcsms_ros.protocols.tripfeed.TripFeed`) or the supervisor's feed
(:class:`~dcsms_ros.protocols.superfeed.SupervisedFeed`), which mode_switch then judges
checkpoint by checkpoint.
"""

from __future__ import annotations

from typing import Any

from geometry_msgs.msg import TwistStamped
from sensor_msgs.msg import JointState

from dcsms_ros.cdr import JOINT_STATE, TWIST_STAMPED, Batch, BatchReader
from dcsms_ros.core import fastsim, topics
from dcsms_ros.core.checkpoints import CheckpointFeed
from dcsms_ros.core.config import SystemConfig
from dcsms_ros.core.modes import Mode
from dcsms_ros.core.sosfilter import BlockFilter, sosfilt
from dcsms_ros.core.supervision import LazyGains, make_supervisor, settings_from
from dcsms_ros.core.supervisor import Transition
from dcsms_ros.core.trip import TripChecker
from dcsms_ros.protocols.superfeed import SupervisedFeed
from dcsms_ros.protocols.tripfeed import TripFeed
from dcsms_ros.ros import qos
from dcsms_ros.ros.hotpath import HotPath
from dcsms_ros.ros.stability import StabilityGuard

#: Reader depth of the trip monitor's velocity streams (samples).
TRIP_DEPTH = 4000


def _trip_feed(cfg: SystemConfig, block_filter: BlockFilter) -> TripFeed:
    return TripFeed(TripChecker(cfg.control, cfg.plant.rate_hz, cfg.plant.num_stages,
                                cfg.plant.dof, block_filter), cfg.plant.rate_hz)


class TableWatch:
    """The streams mode_switch judges and the feeds they go to.

    Parameters
    ----------
    hot : HotPath
        mode_switch's hot path (its detached subscriptions are drained here).
    cfg : SystemConfig
        The running configuration.
    mode : Mode
        The initial mode (the supervisor's user mode).
    guard : StabilityGuard
        The supervisor's stability verdict is the guard's, on the live configuration.
    lockstep : bool
        Lockstep QoS (reliable, transient local: every sample from 0) or real time.
    watch : bool
        ``trip_enabled``: subscribe and judge; False: nothing is watched.

    Attributes
    ----------
    feed : TripFeed
        The stage velocities aligned for the trip checker.
    sfeed : SupervisedFeed or None
        The supervisor's feed (None without the supervisor, or without a watch).
    """

    def __init__(self, hot: HotPath, cfg: SystemConfig, mode: Mode, guard: StabilityGuard,
                 lockstep: bool, watch: bool) -> None:
        self.hot = hot
        n = cfg.plant.num_stages
        # composed, numba is loaded (the plant's) and every us is the one driver thread's: the
        # compiled block filter, the same bits (a checkpoint's three Python band-passes took
        # ~180 us of the ~1 ms a composed lockstep checkpoint costs, docs/performance.md)
        self._block: BlockFilter = (fastsim.sosfilt if hot.bus is not None and
                                    fastsim.available() else sosfilt)
        self.feed = _trip_feed(cfg, self._block)
        self.sfeed: SupervisedFeed | None = None
        if watch and cfg.supervisor.enabled:
            sup = make_supervisor(cfg, mode, guard.allow)
            sup.stable = lambda m: guard.refuse_mode(m) is None
            self.sfeed = SupervisedFeed(self.feed, CheckpointFeed(cfg, self._block), sup)
        self._forces = BatchReader(JOINT_STATE)
        self._twists = [BatchReader(TWIST_STAMPED) for _ in range(n + 1)]  # stages, ground
        self._cols = [2] if cfg.plant.dof == 1 else list(range(6))  # z, or the whole twist
        self._trip_subs: list[Any] = []
        if not watch:
            return
        # reliable and (lockstep) transient local: every sample from 0, in order; no wake-up
        # per sample: the queues are drained in blocks
        tq = qos.stream_pub(lockstep, durable=True)
        tq.depth = TRIP_DEPTH
        self._trip_subs = [hot.detached(TwistStamped, topics.LOCAL.velocity(f"stage{i + 1}"),
                                        tq, raw=True) for i in range(n)]
        if self.sfeed is not None:
            self._ground_sub = hot.detached(TwistStamped, topics.LOCAL.velocity("ground"), tq,
                                            raw=True)
            fq = qos.stream_pub(lockstep, durable=True)
            fq.depth = TRIP_DEPTH
            self._force_sub = hot.detached(JointState, topics.LOCAL.actuators_applied, fq,
                                           raw=True)

    def retune(self, cfg: SystemConfig, changed: set[str]) -> None:
        """Accepted parameter changes: a new trip checker for ``control.trip_*``, the
        supervisor's settings from the next checkpoint."""
        if any(n.startswith("control.trip_") for n in changed):
            self.feed = _trip_feed(cfg, self._block)
            if self.sfeed is not None:
                self.sfeed = SupervisedFeed(self.feed, CheckpointFeed(cfg, self._block),
                                            self.sfeed.sup)
        if self.sfeed is not None and any(n.startswith(("supervisor.", "control.trip_rms"))
                                          for n in changed):
            self.sfeed.sup.s = settings_from(cfg)

    def floor_retuned(self, cfg: SystemConfig) -> None:
        """A controller's tuning changed: what the floor explains, for the supervisor."""
        if self.sfeed is not None:
            self.sfeed.sup.band_gain = LazyGains(cfg)

    def complete(self, stamp_ns: int) -> bool:
        """True once every stream judged holds its samples through ``stamp_ns``."""
        return (self.sfeed.complete(stamp_ns) if self.sfeed is not None
                else self.feed.complete_ns() >= stamp_ns)

    def drain(self) -> None:
        """Take every queued message of the watched streams into the feeds."""
        # each queue decoded as one batch (~1 us a message against ~2.5 us one by one)
        for i, sub in enumerate(self._trip_subs):
            b = self._take(sub, self._twists[i])
            self.feed.add_block(i, b.stamp_ns, b.fields["twist"][:, self._cols])
        if self.sfeed is None:
            return
        b = self._take(self._ground_sub, self._twists[-1])
        self.sfeed.add_grounds(b.stamp_ns, b.fields["twist"][:, self._cols])
        b = self._take(self._force_sub, self._forces)
        self.sfeed.add_forces(b.stamp_ns, b.fields["effort"])

    def requested(self, target: Mode) -> Transition:
        """The user switched to ``target`` (supervisor on): its transition, from the newest
        sample in."""
        assert self.sfeed is not None
        self.drain()
        k = self.sfeed.newest_sample()
        self.sfeed.sup.request(target, k, k / self.feed.rate)
        return self.sfeed.sup.transitions[-1]

    def latched(self, reason: str, stamp_ns: int) -> str:
        """The state label of a plain trip (no supervisor) on the checkpoint ``stamp_ns``."""
        k = self.feed.index(stamp_ns)
        return f"LATCHED Passive at {k / self.feed.rate:.4f} s: {reason} (no supervisor)"

    def reset(self) -> str:
        """``reset_trip``: what arrived before belongs to the tripped past; returns the new
        state label."""
        self.drain()
        if self.sfeed is not None:
            k = self.sfeed.newest_sample()
            self.sfeed.sup.reset(k, k / self.feed.rate)
            return self.sfeed.sup.transitions[-1].label
        self.feed.reset()
        k = self.feed.index(max(self.feed.judged_ns, 0))
        return f"OFF Passive at {k / self.feed.rate:.4f} s: reset_trip"

    def status(self) -> dict[str, object]:
        """Diagnostic values: stream gaps, the supervisor's state, each stage's band RMS."""
        sup = self.sfeed.sup if self.sfeed is not None else None
        values: dict[str, object] = {"trip_gaps": self.feed.gaps,
                                     "supervisor": sup.state.value if sup else "off"}
        values.update({f"rms_stage{i + 1}_mps": " ".join(f"{x:.3g}" for x in m.rms)
                       for i, m in enumerate(self.feed.checker.monitors)})
        return values

    def _take(self, sub: Any, reader: BatchReader) -> Batch:
        return reader.read(self.hot.take(sub))


__all__ = ["TRIP_DEPTH", "TableWatch"]
