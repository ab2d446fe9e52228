"""Spectra and time series out of the analysis: npz / mat / csv equal an independent scipy
estimate from the same bag, and each other."""

from __future__ import annotations

import csv
import json
from pathlib import Path

import numpy as np
import pytest
from rosbags.rosbag2 import Reader
from rosbags.typesys import Stores, get_typestore
from scipy import io as sio
from scipy import signal

from dcsms_ros.analysis.mcapwrite import McapBagWriter
from dcsms_ros.cli import main

# every test here reads bags of 20-60 s runs made by session fixtures
pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def decoded(closed_loop_bag: Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """Stamps and z values of the velocity and excitation topics, read with rosbags alone."""
    return _decoded(closed_loop_bag)


def _decoded(bag: Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    out = {}
    ts = get_typestore(Stores.ROS2_JAZZY)
    with Reader(bag) as r:
        for topic in ("/dcsms/velocity/ground", "/dcsms/velocity/stage1",
                      "/dcsms/velocity/stage2", "/dcsms/force/excitation"):
            conns = [c for c in r.connections if c.topic == topic]
            msgs = [ts.deserialize_cdr(bytes(d), c.msgtype) for c, _, d in r.messages(conns)]
            stamp = np.array([m.header.stamp.sec * 10**9 + m.header.stamp.nanosec
                              for m in msgs])
            if "force" in topic:
                val = np.array([m.wrench.force.z for m in msgs])
            else:
                val = np.array([m.twist.linear.z for m in msgs])
            out[topic.rsplit("/", 1)[-1]] = (stamp, val)
    return out


@pytest.fixture(scope="module")
def exported(closed_loop_bag: Path, tmp_path_factory: pytest.TempPathFactory) -> dict:
    outs = {}
    for fmt in ("npz", "mat", "csv"):
        out = tmp_path_factory.mktemp(fmt)
        # 1 s settle: the bag's Passive parts (3 s and 10 s) are shorter than the model's 7 s
        assert main(["analyze", str(closed_loop_bag), "--out", str(out), "--export", fmt,
                     "--settle", "1"]) == 0
        outs[fmt] = out
    return outs


def _segments(out: Path) -> list[dict[str, str]]:
    with open(out / "segments.csv", newline="") as fh:
        return list(csv.DictReader(fh))


def test_npz_equals_scipy(decoded: dict, exported: dict) -> None:
    """Per segment: H1 and coherence equal scipy's csd/welch/coherence on the same samples with
    the same segment length (0.2 dB, 0.02 rad and 0.02 where the coherence is above 0.8);
    the ASDs equal scipy's welch to 1e-3 up to 100 Hz (the analysis keeps float32 samples)."""
    data = decoded
    segs = _segments(exported["npz"])
    assert [s["file"] for s in segs] == ["seg01_dfbc_ffc_excited", "seg02_passive_excited",
                                         "seg03_passive"]
    checked = {"v_b": 0, "f_p2": 0}
    for s in segs:
        d = np.load(exported["npz"] / f"{s['file']}.npz")
        nper = int(d["nperseg"])
        t0, t1 = float(d["t_start_s"]) * 1e9, float(d["t_end_s"]) * 1e9
        sig = {}
        for name, (stamp, val) in data.items():
            sel = (stamp >= t0 - 1) & (stamp < t1 - 1)
            sig[name] = val[sel]
        fs = float(d["fs_hz"])
        pairs = [("ground", "stage1", "h1_v_p1_v_b_z"), ("ground", "stage2", "h1_v_p2_v_b_z"),
                 ("excitation", "stage1", "h1_v_p1_f_p2_z"),
                 ("excitation", "stage2", "h1_v_p2_f_p2_z")]
        for xin, yout, key in pairs:
            if key not in d.files:
                assert xin == "excitation" and s["file"] == "seg03_passive"
                continue
            x, y = sig[xin], sig[yout]
            f, pxy = signal.csd(x, y, fs, nperseg=nper)
            _, pxx = signal.welch(x, fs, nperseg=nper)
            _, coh = signal.coherence(x, y, fs, nperseg=nper)
            np.testing.assert_allclose(d["freq_hz"], f)
            h = pxy / pxx
            ok = coh > 0.8
            got = d[key]
            np.testing.assert_allclose(20 * np.log10(np.abs(got[ok])),
                                       20 * np.log10(np.abs(h[ok])), atol=0.2, err_msg=key)
            np.testing.assert_allclose(np.angle(got[ok] / h[ok]), 0.0, atol=0.02, err_msg=key)
            np.testing.assert_allclose(d["coh_" + key[3:]][ok], coh[ok], atol=0.02, err_msg=key)
            checked[key.split("_", 3)[-1][:-2]] += int(ok.sum())
        for name, key in (("ground", "asd_v_b_z"), ("stage2", "asd_v_p2_z"),
                          ("excitation", "asd_f_p2_z")):
            if key not in d.files:
                continue
            _, p = signal.welch(sig[name], fs, nperseg=nper)
            band = f <= 100.0  # beyond, float32 rounding of the samples shows in the floor
            np.testing.assert_allclose(d[key][band], np.sqrt(p[band]), rtol=1e-3, err_msg=key)
        # one-third-octave RMS: the PSD integrated over each band (bins split at the edges)
        df = f[1] - f[0]
        _, p2 = signal.welch(sig["stage2"], fs, nperseg=nper)
        for c, rms in zip(d["third_octave_centre_hz"], d["third_octave_rms_v_p2_z"],
                          strict=True):
            lo, hi = c * 10 ** -0.05, c * 10 ** 0.05
            w = np.clip(np.minimum(f + df / 2, hi) - np.maximum(f - df / 2, lo), 0, None)
            assert rms == pytest.approx(np.sqrt(np.sum(p2 * w)), rel=1e-5)
    assert checked["v_b"] > 100 and checked["f_p2"] > 500, checked


def test_mat_and_csv_hold_the_npz_values(exported: dict) -> None:
    """The mat file has the npz's arrays (complex as complex); the csv tables have them with
    the unit of every column in the header."""
    for s in _segments(exported["npz"])[:2]:
        d = np.load(exported["npz"] / f"{s['file']}.npz")
        m = sio.loadmat(exported["mat"] / f"{s['file']}.mat")
        arrays = [k for k in d.files if d[k].ndim == 1 and d[k].dtype != np.str_]
        assert "h1_v_p2_v_b_z" in arrays and "h1_v_p2_f_p2_z" in arrays
        for k in arrays:
            np.testing.assert_array_equal(m[k].ravel(), d[k], err_msg=k)
        assert str(m["mode"][0]) == str(d["mode"])
        with open(exported["csv"] / f"{s['file']}_frf.csv", newline="") as fh:
            header = next(csv.reader(fh))
        table = np.loadtxt(exported["csv"] / f"{s['file']}_frf.csv", delimiter=",",
                           skiprows=1)
        assert header[0] == "freq_hz [Hz]"
        col = header.index("h1_v_p2_f_p2_z_re [(m/s)/N]")
        assert header[col + 1] == "h1_v_p2_f_p2_z_im [(m/s)/N]"
        assert header[col + 2] == "coh_v_p2_f_p2_z [-]"
        h = d["h1_v_p2_f_p2_z"]
        np.testing.assert_allclose(table[:, col] + 1j * table[:, col + 1], h, rtol=1e-9,
                                   atol=1e-9 * np.abs(h).max())
        with open(exported["csv"] / f"{s['file']}_third_octave.csv", newline="") as fh:
            assert "third_octave_rms_v_p2_z [m/s]" in next(csv.reader(fh))


def test_export_needs_out(closed_loop_bag: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["analyze", str(closed_loop_bag), "--export", "npz"]) == 2
    assert "--export needs --out" in capsys.readouterr().err


@pytest.mark.parametrize("fmt", ["csv", "npz"])
def test_timeseries_export(closed_loop_bag: Path, decoded: dict, tmp_path: Path,
                           fmt: str) -> None:
    """dcsms export: velocities and forces in SI units, equal to the bag's messages; the mode
    timeline; units in the csv headers (csv: the topics named)."""
    out = tmp_path / "ts"
    pick = [] if fmt == "npz" else ["--topics", "/dcsms/velocity/stage2",
                                    "/dcsms/force/exc*"]
    assert main(["export", str(closed_loop_bag), "--format", fmt, "--out", str(out),
                 *pick]) == 0
    data = decoded
    stamp, vz = data["stage2"]
    _, fz = data["excitation"]
    if fmt == "npz":
        d = np.load(out / "timeseries.npz")
        np.testing.assert_array_equal(d["velocity_stage2_vz"], vz)
        np.testing.assert_array_equal(d["velocity_stage2_stamp_ns"], stamp)
        np.testing.assert_array_equal(d["force_excitation_fz"], fz)
        np.testing.assert_allclose(d["velocity_stage2_t_s"], (stamp - stamp[0]) * 1e-9)
        assert list(d["mode_label"]) == ["DFBC+FFC", "Passive"]
        assert "actuators_applied_effort_stage1_a0" in d.files
        return
    with open(out / "velocity_stage2.csv", newline="") as fh:
        header = next(csv.reader(fh))
    assert header == ["t_s [s]", "stamp_ns [ns]", "log_ns [ns]", "vx [m/s]", "vy [m/s]",
                      "vz [m/s]", "wx [rad/s]", "wy [rad/s]", "wz [rad/s]"]
    table = np.loadtxt(out / "velocity_stage2.csv", delimiter=",", skiprows=1)
    np.testing.assert_array_equal(table[:, 5], vz)
    np.testing.assert_array_equal(table[:, 1].astype(np.int64), stamp)
    with open(out / "force_excitation.csv", newline="") as fh:
        assert next(csv.reader(fh))[3:6] == ["fx [N]", "fy [N]", "fz [N]"]
    with open(out / "mode.csv", newline="") as fh:
        assert [r[1] for r in csv.reader(fh)][1:] == ["DFBC+FFC", "Passive"]
    assert sorted(p.name for p in out.iterdir()) == ["force_excitation.csv", "mode.csv",
                                                     "velocity_stage2.csv"]


@pytest.mark.parametrize("extra, message", [
    (["--topics", "/dcsms/nope"], "no such topic"),
    (["--topics", "/dcsms/mode"], "no numeric samples"),
])
def test_timeseries_export_errors(closed_loop_bag: Path, tmp_path: Path, extra: list[str],
                                  message: str, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "x"
    assert main(["export", str(closed_loop_bag), "--out", str(out), *extra]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and message in err
    assert not out.exists()


def test_analysis_reports_what_each_segment_estimates(exported: dict) -> None:
    """The excited segments give the mobility, the quiet ground-dominated one the
    transmissibility; each is compared with the loop model on every usable bin (the plant is
    the configuration: the model explains the estimate to within its random error) and the
    count is in the report."""
    doc = json.loads((exported["npz"] / "summary.json").read_text())
    segs = doc["segments"]
    assert [s["segment"] for s in segs] == ["DFBC+FFC + excitation stage2.z",
                                            "Passive + excitation stage2.z", "Passive"]
    for seg in segs:
        z = seg["axes"]["z"]
        kind = "mobility" if seg["excited"] else "transmissibility"
        other = "transmissibility" if seg["excited"] else "mobility"
        est = z["estimates"][kind]
        assert est["status"] == "estimated", (seg["segment"], est)
        assert z["estimates"][other]["status"] in ("not estimated", "unavailable")
        assert max(est["usable_bins"].values()) > 80
        for stage, cmp in z["model"][kind].items():
            assert cmp["compared_bins"] == est["usable_bins"][stage] >= 10
            assert cmp["rms_error_db"] < 0.6, (seg["segment"], stage, cmp)
    assert segs[0]["excited"] == {"stage": "stage2", "axes": ["z"]} and not segs[2]["excited"]
    assert doc["segments"][2]["axes"]["z"]["normalized"] == 1.0  # the quiet one is Table 4's
    md = (exported["npz"] / "report.md").read_text()
    assert "## What each segment can estimate" in md and "compared bins (of band)" in md


def test_export_of_a_bag_without_the_default_topics_names_them(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A bag holding only a user's TwistStamped topic: the default selection finds nothing,
    and the one-line error says what it looked for and how to choose."""
    ts = get_typestore(Stores.ROS2_JAZZY)
    twist = ts.types["geometry_msgs/msg/TwistStamped"]
    header = ts.types["std_msgs/msg/Header"]
    stamp = ts.types["builtin_interfaces/msg/Time"]
    vec = ts.types["geometry_msgs/msg/Vector3"]
    msg = twist(header(stamp(0, 0), "base"),
                ts.types["geometry_msgs/msg/Twist"](vec(0.0, 0.0, 1e-6), vec(0.0, 0.0, 0.0)))
    bag = tmp_path / "user"
    w = McapBagWriter(bag)
    w.add_topic("/dcsms/user/twist", "geometry_msgs/msg/TwistStamped")
    w.write("/dcsms/user/twist", 1, bytes(ts.serialize_cdr(msg, twist.__msgtype__)))
    w.close()
    out = tmp_path / "x"
    assert main(["export", str(bag), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "/dcsms/velocity/*" in err and "--topics" in err
    assert not out.exists()
    assert main(["export", str(bag), "--out", str(out), "--topics", "/dcsms/user/*"]) == 0
    assert (out / "user_twist.csv").exists()


def _graph_messages():
    """(TwistStamped class, ``twist(stamp_ns, vz)`` and ``text(label)`` serializers) for
    bags written by hand."""
    ts = get_typestore(Stores.ROS2_JAZZY)
    T = ts.types
    twist_t = T["geometry_msgs/msg/TwistStamped"]

    def twist(stamp_ns: int, vz: float) -> bytes:
        sec, nsec = divmod(stamp_ns, 10**9)
        msg = twist_t(T["std_msgs/msg/Header"](T["builtin_interfaces/msg/Time"](sec, nsec),
                                                "stage2"),
                      T["geometry_msgs/msg/Twist"](T["geometry_msgs/msg/Vector3"](0, 0, vz),
                                                   T["geometry_msgs/msg/Vector3"](0, 0, 0)))
        return bytes(ts.serialize_cdr(msg, twist_t.__msgtype__))

    def text(label: str) -> bytes:
        s = T["std_msgs/msg/String"](label)
        return bytes(ts.serialize_cdr(s, "std_msgs/msg/String"))

    return twist_t, twist, text


def test_export_places_switches_on_the_stamp_axis_and_keeps_zero_stamped_rows(
        tmp_path: Path) -> None:
    """A graph bag: stamps in simulated time from 0, bag times on the wall clock (~1.8e18
    ns). The switches (String, bag time only) must land on the samples' own ``t_s`` axis;
    they came out at ~1.8e9 s. A user topic whose stamps stay zero keeps every message that
    differs (the stamp alone made them one row)."""
    twist_t, twist, text = _graph_messages()
    wall = 1_795_000_000 * 10**9
    bag = tmp_path / "graph"
    w = McapBagWriter(bag)
    w.add_topic("/dcsms/velocity/stage2", twist_t.__msgtype__)
    w.add_topic("/dcsms/mode", "std_msgs/msg/String")
    w.add_topic("/dcsms/user/twist", twist_t.__msgtype__)
    w.write("/dcsms/mode", wall - 10**8, text("DFBC+FFC"))
    for k in range(1000):
        log = wall + k * 10**6 + 200_000
        if k == 500:
            w.write("/dcsms/mode", log - 100_000, text("Passive"))
        w.write("/dcsms/velocity/stage2", log, twist(k * 10**6, 1e-6 * k))
        if k < 3:
            w.write("/dcsms/user/twist", log + 1, twist(0, float(k)))
    w.close()
    out = tmp_path / "x"
    assert main(["export", str(bag), "--out", str(out), "--topics", "/dcsms/velocity/*",
                 "/dcsms/user/*"]) == 0
    with open(out / "mode.csv", newline="") as fh:
        rows = list(csv.reader(fh))[1:]
    assert [r[1] for r in rows] == ["DFBC+FFC", "Passive"]
    np.testing.assert_allclose([float(r[0]) for r in rows], [0.0, 0.5])
    user = np.loadtxt(out / "user_twist.csv", delimiter=",", skiprows=1, dtype=object)
    np.testing.assert_array_equal(user[:, 5].astype(float), [0.0, 1.0, 2.0])
    # their only time: the bag's, exact to the nanosecond
    np.testing.assert_array_equal(user[:, 2].astype(np.int64),
                                  [wall + k * 10**6 + 200_001 for k in range(3)])


def test_export_of_reordered_stamps_keeps_each_rows_bag_time(tmp_path: Path) -> None:
    """A publisher that swaps each pair of stamps: rows come out in stamp order, each with its
    own bag time, and a switch lands at the stamp of the first sample recorded after it (the
    bag times were left in arrival order against rows sorted by stamp)."""
    twist_t, twist, text = _graph_messages()
    bag = tmp_path / "swapped"
    w = McapBagWriter(bag)
    w.add_topic("/dcsms/velocity/stage2", twist_t.__msgtype__)
    w.add_topic("/dcsms/mode", "std_msgs/msg/String")
    wall = 1_795_000_000 * 10**9
    sent = [k + 1 if k % 2 == 0 else k - 1 for k in range(100)]  # 1, 0, 3, 2, ...
    w.write("/dcsms/mode", wall - 10**8, text("FBC"))
    for i, k in enumerate(sent):
        if i == 51:  # before the 52nd message, the one of stamp 50
            w.write("/dcsms/mode", wall + i * 10**6 - 1, text("Passive"))
        w.write("/dcsms/velocity/stage2", wall + i * 10**6, twist(k * 10**6, float(k)))
    w.close()
    out = tmp_path / "x"
    assert main(["export", str(bag), "--out", str(out), "--format", "npz"]) == 0
    d = np.load(out / "timeseries.npz")
    np.testing.assert_array_equal(d["velocity_stage2_stamp_ns"], np.arange(100) * 10**6)
    np.testing.assert_array_equal(d["velocity_stage2_vz"], np.arange(100.0))
    arrival = {k: wall + i * 10**6 for i, k in enumerate(sent)}
    np.testing.assert_array_equal(d["velocity_stage2_log_ns"], [arrival[k] for k in range(100)])
    assert list(d["mode_label"]) == ["FBC", "Passive"]
    # the first message recorded after each switch: stamp 1 ms (sent first), stamp 50 ms
    np.testing.assert_allclose(d["mode_t_s"], [0.001, 0.050])
