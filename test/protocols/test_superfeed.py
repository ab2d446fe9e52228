"""The supervisor fed from separate stamped streams (the graph's view) decides as the batch
engine does: lockstep (one checkpoint per call, each stream complete) equals it exactly; real
time (chunks in any order, a lag) too when nothing is lost."""

from __future__ import annotations

import numpy as np
import pytest

from dcsms_ros.core.checkpoints import CheckpointFeed
from dcsms_ros.core.config import SystemConfig, with_overrides
from dcsms_ros.core.engine import SimResult, simulate
from dcsms_ros.core.modes import Mode
from dcsms_ros.core.supervision import make_supervisor
from dcsms_ros.core.trip import TripChecker
from dcsms_ros.protocols.superfeed import SupervisedFeed
from dcsms_ros.protocols.tripfeed import TripFeed


def sample_ns(k: int, rate_hz: float) -> int:
    """The stamp of sample k (as the plant stamps it)."""
    return int(round(k * 1e9 / rate_hz))


QUICK = {"supervisor.recover_after_s": 0.5, "supervisor.settle_s": 0.3}


@pytest.fixture
def burst(cfg: SystemConfig) -> tuple[SystemConfig, SimResult]:
    """Table1 DFBC+FFC with a burst on the floor from 0.5 to 1.2 s (x300)."""
    quick = with_overrides(cfg, QUICK)
    ground = simulate(cfg, Mode.PASSIVE, 3.5, seed=5, trip=False).truth[:, 0].copy()
    fs = cfg.plant.rate_hz
    ground[int(0.5 * fs):int(1.2 * fs)] *= 300.0
    return quick, simulate(quick, Mode.DFBC_FFC, 3.0, ground=ground)


def _feed(cfg: SystemConfig) -> SupervisedFeed:
    c = cfg.plant
    trip = TripFeed(TripChecker(cfg.control, c.rate_hz, c.num_stages, c.dof), c.rate_hz)
    return SupervisedFeed(trip, CheckpointFeed(cfg), make_supervisor(cfg, Mode.DFBC_FFC))


def _add(feed: SupervisedFeed, res: SimResult, k: int, rate: float) -> None:
    ns = sample_ns(k, rate)
    for i in range(res.velocity.shape[1] - 1):
        feed.feed.add_block(i, [ns], res.velocity[k, i + 1])
    feed.add_grounds([ns], res.velocity[k, 0])
    feed.add_forces([ns], res.applied[k])


def test_lockstep_feeding_equals_the_batch_engine(burst: tuple[SystemConfig, SimResult]) -> None:
    cfg, res = burst
    assert len(res.supervision) == 3  # RIDE_THROUGH, RECOVERING, ENGAGED
    feed = _feed(cfg)
    rate, every = cfg.plant.rate_hz, feed.feed.checker.every
    got = []
    for k in range(res.t.size):
        # the graph: the checkpoint is asked once the controllers answered sample k; the
        # plant's forces of k are applied (published) only after the verdict
        ns = sample_ns(k, rate)
        for i in range(res.velocity.shape[1] - 1):
            feed.feed.add_block(i, [ns], res.velocity[k, i + 1])
        feed.add_grounds([ns], res.velocity[k, 0])
        if (k + 1) % every == 0:
            assert feed.complete(ns)
            got += feed.step(ns)
        feed.add_forces([ns], res.applied[k])
    assert got == res.supervision


def test_a_checkpoint_waits_for_the_previous_samples_forces(cfg: SystemConfig) -> None:
    feed = _feed(cfg)
    rate, every = cfg.plant.rate_hz, feed.feed.checker.every
    k = every - 1
    for j in range(k + 1):
        ns = sample_ns(j, rate)
        for i in range(cfg.plant.num_stages):
            feed.feed.add_block(i, [ns], np.zeros(cfg.plant.dof))
        feed.add_grounds([ns], np.zeros(cfg.plant.dof))
        if j < k - 1:
            feed.add_forces([ns], np.zeros(2))
    assert not feed.complete(sample_ns(k, rate))
    feed.add_forces([sample_ns(k - 1, rate)], np.zeros(2))
    assert feed.complete(sample_ns(k, rate))


def test_realtime_feeding_in_chunks_and_any_order_decides_the_same(
        burst: tuple[SystemConfig, SimResult]) -> None:
    cfg, res = burst
    feed = _feed(cfg)
    rate = cfg.plant.rate_hz
    got = []
    chunk = 37  # not a multiple of the checkpoint: the feed splits the blocks itself
    for k0 in range(0, res.t.size, chunk):
        for k in range(k0, min(k0 + chunk, res.t.size)):
            _add(feed, res, k, rate)
        got += feed.step()  # real time: every row older than the lag
    got += feed.step(sample_ns(res.t.size - 1, rate))
    assert got == res.supervision


@pytest.mark.parametrize("chunk", [37, 250])
def test_realtime_feeding_drained_blocks_decides_the_same(
        burst: tuple[SystemConfig, SimResult], chunk: int) -> None:
    """The node drains each queue as one block (forces first, stages last): the same
    transitions as the batch engine."""
    cfg, res = burst
    feed = _feed(cfg)
    stamps = np.array([sample_ns(k, cfg.plant.rate_hz) for k in range(res.t.size)])
    got = []
    for k0 in range(0, res.t.size, chunk):
        sl = slice(k0, k0 + chunk)
        feed.add_forces(stamps[sl], res.applied[sl])
        feed.add_grounds(stamps[sl], res.velocity[sl, 0])
        for i in range(res.velocity.shape[1] - 1):
            feed.feed.add_block(i, stamps[sl], res.velocity[sl, i + 1])
        got += feed.step()
    got += feed.step(int(stamps[-1]))
    assert got == res.supervision
