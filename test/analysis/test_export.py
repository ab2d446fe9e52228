"""Batch results as bags: readable everywhere, values round-trip, ground replay and resampling."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag2 import Reader

from dcsms_ros import cdr
from dcsms_ros.analysis.export import sample_times_ns, to_six, write_result_bag
from dcsms_ros.analysis.reader import CONFIG_TOPIC, config_from_yaml
from dcsms_ros.analysis.replay import load_ground, parse_ground_spec, resample
from dcsms_ros.cli.common import default_config_path
from dcsms_ros.core import topics
from dcsms_ros.core.config import load_config
from dcsms_ros.core.engine import SimResult, simulate
from dcsms_ros.core.modes import Mode
from dcsms_ros.errors import BagError

# every test here reads bags of 20-60 s runs made by session fixtures
pytestmark = pytest.mark.slow

CFG = load_config(default_config_path())


@pytest.fixture(scope="module")
def run(tmp_path_factory: pytest.TempPathFactory) -> tuple[SimResult, Path, dict[str, int]]:
    """A 15 s DFBC+FFC -> Passive -> FBC batch run and its bag (shared by the module)."""
    res = simulate(CFG, Mode.DFBC_FFC, 15.0, seed=5,
                   schedule=[(5.0, Mode.PASSIVE), (10.0, Mode.FBC)])
    bag = tmp_path_factory.mktemp("export") / "run"
    counts = write_result_bag(res, bag)
    return res, bag, counts


def _messages(bag: Path) -> dict[str, list[tuple[int, bytes]]]:
    out: dict[str, list[tuple[int, bytes]]] = {}
    with Reader(bag) as r:
        for c, t, raw in r.messages():
            out.setdefault(c.topic, []).append((t, bytes(raw)))
    return out


def test_topics_and_counts_rosbags_and_mcap(run: tuple[SimResult, Path, dict[str, int]]) -> None:
    """rosbags and the independent mcap + mcap_ros2 readers see the same per-topic counts."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    res, bag, counts = run
    k = res.t.size
    # each scheduled switch is a supervisor transition too (ENGAGED <mode>: user set <mode>)
    expected = {topics.SENSORS_RAW: k, topics.ACTUATORS_APPLIED: k, topics.MODE: 3,
                CONFIG_TOPIC: 1, topics.SUPERVISOR_STATE: 2}
    for b in topics.body_names(2):
        expected[topics.truth_topic(b)] = expected[topics.velocity_topic(b)] = k
    for cid in ("fb_stage1", "fb_stage2", "ff_stage1"):
        expected[topics.force_topic(cid)] = k
    assert counts == expected
    with Reader(bag) as r:
        got = Counter(c.topic for c, _, _ in r.messages())
        meta = {c.topic: c.msgcount for c in r.connections}
        qos = {c.topic: c.ext.offered_qos_profiles for c in r.connections}
    assert dict(got) == meta == expected
    assert qos[topics.MODE][0].depth == 1 and qos[CONFIG_TOPIC][0].depth == 1
    mc: Counter[str] = Counter()
    with next(bag.glob("*.mcap")).open("rb") as f:
        for _, channel, _, msg in make_reader(f, decoder_factories=[DecoderFactory()]) \
                .iter_decoded_messages():
            mc[channel.topic] += 1
            assert msg is not None
    assert dict(mc) == expected


def test_values_round_trip(run: tuple[SimResult, Path, dict[str, int]]) -> None:
    """Every exported array decodes back bit-exact, stamps and bag times are sim time."""
    res, bag, _ = run
    msgs = _messages(bag)
    t_ns = sample_times_ns(res)
    assert t_ns[1] == 500_000

    def batch(topic: str, msgtype: str) -> cdr.Batch:
        log = np.array([t for t, _ in msgs[topic]])
        np.testing.assert_array_equal(log, t_ns)
        b = cdr.decode_batch(msgtype, [m for _, m in msgs[topic]])
        assert b.fast
        np.testing.assert_array_equal(b.stamp_ns, t_ns)
        return b

    raw = batch(topics.SENSORS_RAW, cdr.JOINT_STATE)
    assert list(raw.names) == res.channel_names
    np.testing.assert_array_equal(raw.fields["velocity"], res.raw)
    app = batch(topics.ACTUATORS_APPLIED, cdr.JOINT_STATE)
    assert list(app.names) == res.actuator_names
    np.testing.assert_array_equal(app.fields["effort"], res.applied)
    for i, b in enumerate(topics.body_names(2)):
        for top, arr in ((topics.truth_topic(b), res.truth), (topics.velocity_topic(b),
                                                              res.velocity)):
            got = batch(top, cdr.TWIST_STAMPED)
            assert got.frame_id == b
            np.testing.assert_array_equal(got.fields["twist"], to_six(arr[:, i], 1))
    for cid, frame in (("fb_stage1", "stage1"), ("fb_stage2", "stage2"),
                       ("ff_stage1", "stage1")):
        got = batch(topics.force_topic(cid), cdr.WRENCH_STAMPED)
        assert got.frame_id == frame
        np.testing.assert_array_equal(got.fields["wrench"], to_six(res.wrench[cid], 1))
    modes = [(t, cdr.decode_string(m)) for t, m in msgs[topics.MODE]]
    assert modes == [(0, "DFBC+FFC"), (5_000_000_000, "Passive"), (10_000_000_000, "FBC")]
    cfg = config_from_yaml(cdr.decode_string(msgs[CONFIG_TOPIC][0][1]))
    assert cfg.params == CFG.params


def test_analyze_runs_on_batch_bag(run: tuple[SimResult, Path, dict[str, int]]) -> None:
    """dcsms_ros.analysis.report.analyze splits the batch bag into its three modes."""
    from dcsms_ros.analysis.report import analyze

    _, bag, _ = run
    summary = analyze([bag], settle_s=0.5)
    assert [s["mode"] for s in summary.segments] == ["DFBC+FFC", "Passive", "FBC"]
    z = {s["mode"]: s["axes"]["z"]["normalized"] for s in summary.segments}
    assert z["Passive"] == pytest.approx(1.0) and z["DFBC+FFC"] < z["FBC"] < 1.0


def test_replay_reproduces_recorded_ground(run: tuple[SimResult, Path, dict[str, int]]) -> None:
    """The recorded ground velocity replayed at the same rate is the new run's ground, exactly."""
    res, bag, _ = run
    g = load_ground(bag, None, CFG.plant.rate_hz, 1)
    np.testing.assert_array_equal(g, res.velocity[:, 0, :])
    truth = load_ground(*parse_ground_spec(f"{bag}:/dcsms/truth/ground"), CFG.plant.rate_hz, 1)
    np.testing.assert_array_equal(truth, res.truth[:, 0, :])
    again = simulate(CFG, Mode.PASSIVE, 2.0, seed=9, ground=g)
    np.testing.assert_array_equal(again.truth[:, 0, :], g[:again.t.size])


def test_resample_up_and_down_with_anti_aliasing() -> None:
    """500 Hz -> 2 kHz keeps a 3 + 40 Hz signal; 2 kHz -> 500 Hz removes a 400 Hz tone."""
    def sig(t: np.ndarray) -> np.ndarray:
        return np.sin(2 * np.pi * 3 * t) + 0.5 * np.sin(2 * np.pi * 40 * t)

    t_in = np.arange(2000) / 500.0
    up = resample(np.round(t_in * 1e9).astype(np.int64), sig(t_in)[:, None], 2000.0)
    t_out = np.arange(up.shape[0]) / 2000.0
    inner = slice(200, -200)
    assert up.shape[0] == 8000  # ceil(2000 * 4); the last 3 extend the final sample
    assert np.max(np.abs(up[inner, 0] - sig(t_out)[inner])) < 2e-3
    t_fast = np.arange(8000) / 2000.0
    x = sig(t_fast) + np.sin(2 * np.pi * 400 * t_fast)  # above the new Nyquist (250 Hz)
    down = resample(np.round(t_fast * 1e9).astype(np.int64), x[:, None], 500.0)
    t_slow = np.arange(down.shape[0]) / 500.0
    assert np.max(np.abs(down[inner, 0] - sig(t_slow)[inner])) < 1e-2


def test_resample_fills_dropped_samples() -> None:
    """Missing stamps are interpolated on the recorded grid, with a warning."""
    t = np.arange(100, dtype=np.int64) * 500_000
    keep = np.ones(100, bool)
    keep[[10, 50, 51]] = False
    with pytest.warns(RuntimeWarning, match="3 sample"):
        out = resample(t[keep], (t[keep] * 1e-9)[:, None], 2000.0)
    np.testing.assert_allclose(out[:, 0], t * 1e-9, atol=1e-12)


def test_bad_ground_input(tmp_path: Path, run: tuple[SimResult, Path, dict[str, int]]) -> None:
    """A missing bag, an absent topic or a non-twist topic: BagError naming the bag."""
    _, bag, _ = run
    with pytest.raises(BagError, match="no such bag"):
        load_ground(tmp_path / "none", None, 2000.0, 1)
    with pytest.raises(BagError, match="no topic /dcsms/nope"):
        load_ground(bag, "/dcsms/nope", 2000.0, 1)
    with pytest.raises(BagError, match="expected geometry_msgs/msg/TwistStamped"):
        load_ground(bag, topics.MODE, 2000.0, 1)
    assert parse_ground_spec("a:b/c") == (Path("a:b/c"), None)
