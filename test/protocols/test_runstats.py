"""Run statistics: latency quantiles against numpy's, the summary from a plant report."""

from __future__ import annotations

import math

import numpy as np
import pytest

from dcsms_ros.protocols.runstats import BINS_PER_DECADE, LatencyHistogram, summarize

#: half a bin in log space: the largest relative error of a quantile read from the histogram
HALF_BIN = 10 ** (0.5 / BINS_PER_DECADE) - 1.0


@pytest.mark.parametrize("q", [0.5, 0.9, 0.99])
def test_latency_quantiles_match_numpy_within_half_a_bin(q: float) -> None:
    """Log-normal latencies around 0.3 ms: each quantile within one bin of the exact one."""
    rng = np.random.default_rng(3)
    lat = np.exp(rng.normal(math.log(3e-4), 0.5, 20000))
    h = LatencyHistogram()
    for x in lat:
        h.add(float(x))
    exact = float(np.quantile(lat, q))
    assert h.count == lat.size
    assert abs(h.quantile(q) / exact - 1.0) <= 2 * HALF_BIN


def test_latency_out_of_range_and_empty() -> None:
    """Nothing counted: nan; beyond the range: the end bins, not an error."""
    h = LatencyHistogram()
    assert math.isnan(h.quantile(0.5))
    h.add(0.0)
    h.add(1e3)
    assert h.quantile(0.0) < 2e-5 and h.quantile(1.0) > 5.0


def test_summary_from_a_plant_report_and_bag_counts() -> None:
    """late = overruns + late steps + lockstep timeouts, a part of the deadlines that passed
    (the samples and the 25 dropped); recorded of expected over the recorded streams."""
    plant = {"sample": "4000", "overruns": "25", "late_steps": "5", "lockstep_timeouts": "10",
             "stale_samples": "7", "latency_p50_ms": "0.3100", "latency_p99_ms": "1.2000"}
    counts = {"/a": 4000, "/b": 3990, "/dcsms/mode": 3}
    s = summarize(plant, counts, ["/a", "/b"])
    assert (s.samples, s.late, s.stale, s.recorded, s.samples_x_streams) == (4000, 40, 7, 7990,
                                                                             8000)
    assert s.latency_p99_s == pytest.approx(1.2e-3)
    assert s.line() == ("samples 4000, late 40 (0.994 %), stale forces 7, control latency "
                        "p50/p99 0.310/1.200 ms, recorded 7990 of 8000 messages")
    assert s.to_dict()["late_fraction"] == pytest.approx(40 / 4025)
    # real time: samples x streams is not what was published; the line does not say "of"
    rt = summarize({**plant, "schedule": "realtime"}, counts, ["/a", "/b"])
    assert rt.line().endswith("recorded 7990 stream messages (samples x streams = 8000)")
    assert not rt.to_dict()["lockstep"]
    bare = summarize({"sample": "10"}, None, [])
    assert bare.line().endswith("p50/p99 -/- ms, not recorded")


def test_summary_against_what_was_published() -> None:
    """With the recorder's published counts for every recorded stream, the line says recorded
    of published (real time too); a stream without one falls back to the scale."""
    plant = {"sample": "4000", "schedule": "realtime", "stale_samples": "0"}
    counts = {"/a": 4000, "/b": 3890}
    s = summarize(plant, counts, ["/a", "/b"], {"/a": 4000, "/b": 3950, "/x": 5})
    assert (s.recorded, s.published, s.samples_x_streams) == (7890, 7950, 8000)
    assert s.line().endswith("recorded 7890 of 7950 messages")
    partial = summarize(plant, counts, ["/a", "/b"], {"/a": 4000})
    assert partial.published is None
    assert partial.line().endswith("recorded 7890 stream messages (samples x streams = 8000)")


def test_a_stream_the_bag_lacks_counts_as_none_recorded() -> None:
    """A stream asked for and absent from the bag (a node's part never closed) is not left
    out of the line: its samples count, none recorded, and its publisher's count is unknown."""
    plant = {"sample": "4000", "schedule": "realtime", "stale_samples": "0"}
    s = summarize(plant, {"/a": 4000, "/b": 3890}, ["/a", "/b", "/c"],
                  {"/a": 4000, "/b": 3950})
    assert (s.recorded, s.published, s.samples_x_streams) == (7890, None, 12000)
    assert s.line().endswith("recorded 7890 stream messages (samples x streams = 12000)")
    lock = summarize({"sample": "4000"}, {"/a": 4000}, ["/a", "/c"])
    assert lock.line().endswith("recorded 4000 of 8000 messages")


@pytest.mark.parametrize(("late", "schedule", "warns"), [
    (400, "realtime", False), (401, "realtime", True), (4000, "lockstep", False)])
def test_a_real_time_run_with_more_than_one_percent_late_warns(late: int, schedule: str,
                                                              warns: bool) -> None:
    """Above 1 % of late samples a real-time summary warns (lockstep's timeouts do not delay
    the loop: the plant waits for the answers)."""
    s = summarize({"sample": "40000", "late_steps": str(late), "schedule": schedule}, None, [])
    w = s.warning()
    assert (w is not None) == warns
    if warns:
        assert w is not None and w.startswith("1 % of the samples missed their deadline")


@pytest.mark.parametrize(("stale", "late", "schedule", "says"), [
    (1200, 0, "realtime", None), (1201, 0, "realtime", ["1 % of the controllers' forces"]),
    (60000, 4000, "realtime", ["10 % of the samples", "50 % of the controllers' forces"]),
    (60000, 0, "lockstep", None)])
def test_a_real_time_run_with_more_than_one_percent_stale_forces_warns(
        stale: int, late: int, schedule: str, says: list[str] | None) -> None:
    """Stale forces are part of samples x controllers (3 here: 120,000): above 1 % of them a
    real-time summary warns that the loop was open that often, with the late samples in the
    same line when both are above their bound."""
    s = summarize({"sample": "40000", "late_steps": str(late), "schedule": schedule,
                   "stale_samples": str(stale), "controllers": "3"}, None, [])
    assert s.forces == 120000
    w = s.warning()
    if says is None:
        assert w is None
        return
    assert w is not None and w.count("\n") == 0 and "--composed" in w
    assert "--composed" not in (s.warning(composed=True) or "")  # already composed
    assert [w.index(x) for x in says] == sorted(w.index(x) for x in says)
    assert ("missed their deadline" in w) == (late > 0)



def test_late_fraction_of_a_plant_that_fell_behind_stays_a_fraction() -> None:
    """A plant at half speed drops as many deadlines as it computes samples: 4,000 samples,
    4,000 dropped, 760 computed after the next was due are 4,760 of 8,000 deadlines missed
    (59.5 %), not 119 % of the samples (what the summary printed before)."""
    plant = {"sample": "4000", "overruns": "4000", "late_steps": "760",
             "schedule": "realtime", "controllers": "3"}
    s = summarize(plant, None, [])
    assert s.late == 4760 and s.late_fraction == pytest.approx(0.595)
    assert "late 4760 (59.5 %)" in s.line()
    warning = s.warning()
    assert warning is not None and warning.startswith("59.5 % of the samples missed")
    assert summarize({"sample": "0", "schedule": "realtime"}, None, []).late_fraction == 0.0


@pytest.mark.parametrize(("schedule", "composed"), [("realtime", False), ("lockstep", True)])
def test_a_bag_that_lacks_published_messages_warns_in_any_schedule(schedule: str,
                                                                   composed: bool) -> None:
    """The user's per-process run of 2026-11-28 printed "recorded 71951 of 407353 messages"
    and no warning; the bag lacked 82 %. A loss warns, with its count and share, after the
    timing's own warning and hint; a complete bag, or one whose publications are not known,
    does not."""
    plant = {"sample": "40000", "schedule": schedule, "late_steps": "1050",
             "stale_samples": "36489", "controllers": "3"}
    counts = {"/a": 40000, "/b": 31951}
    s = summarize(plant, counts, ["/a", "/b"], {"/a": 367353, "/b": 40000})
    assert s.lost == 335402 and s.to_dict()["lost"] == 335402
    w = s.warning(composed=composed)
    assert w is not None and w.count("\n") == 0
    assert w.endswith("the bag lacks 335402 of the 407353 messages published (82.3 %): the "
                      "recorder did not keep up (--record-topics with fewer topics lightens "
                      f"it{'' if composed else '; --composed records in the process'})")
    if schedule == "realtime":  # the timing's hint stays with the timing
        assert w.index("missed their deadline") < w.index("--lockstep") < w.index("lacks")
    whole = summarize(plant, {"/a": 40000}, ["/a"], {"/a": 40000})
    assert whole.lost == 0 and "lacks" not in (whole.warning() or "")
    unknown = summarize(plant, counts, ["/a", "/b"], None)
    assert unknown.lost == 0 and "lacks" not in (unknown.warning() or "")
    assert summarize({**plant, "schedule": "lockstep"}, {"/a": 40000}, ["/a"],
                     {"/a": 40000}).warning() is None


@pytest.mark.parametrize(("steal", "named"), [(None, False), (0.0199, False), (0.02, True),
                                              (0.117, True)])
def test_a_late_warning_names_the_hypervisor_s_share_from_two_percent(
        steal: float | None, named: bool) -> None:
    """Late samples on a host whose hypervisor took >= 2 % of the CPU: the warning says how
    much (a user cannot tell that from the graph's figures); below it, or unknown, it does
    not. The share is in the JSON either way."""
    s = summarize({"sample": "40000", "late_steps": "4394", "schedule": "realtime"}, None, [],
                  steal=steal)
    w = s.warning()
    assert w is not None and w.count("\n") == 0
    assert ("steal time" in w) == named
    if named:
        assert steal is not None and f"took {100 * steal:.3g} % of the machine's CPU" in w
    assert s.to_dict()["steal"] == steal


@pytest.mark.parametrize(("woke", "paused"), [(0, 0), (1, 0), (3900, 0), (0, 7), (12, 300)])
def test_a_late_warning_says_how_many_the_machine_took(woke: int, paused: int) -> None:
    """The plant's ``woke_late_steps`` (of its late samples, those whose deadline passed
    while its loop waited to run after its wake-up time and nothing of its process ran) and
    ``paused_steps`` (those a pause while it worked pushed back) are in the JSON, and the
    late-sample warning names them when there are any."""
    plant = {"sample": "40000", "late_steps": "4394", "woke_late_steps": str(woke),
             "paused_steps": str(paused), "schedule": "realtime"}
    s = summarize(plant, None, [])
    w = s.warning()
    assert w is not None and (s.to_dict()["woke_late"], s.to_dict()["paused"]) == (woke, paused)
    assert (f"{woke} of the 4394 passed while the plant's loop waited to run after its "
            f"wake-up time and nothing of its process ran, {paused} more were pushed back by "
            f"such a pause while it worked" in w) == bool(woke or paused)
    old = summarize({k: v for k, v in plant.items()
                     if k not in ("woke_late_steps", "paused_steps")}, None, [])
    assert (old.woke_late, old.paused) == (0, 0)  # a plant from before the counts


def test_steal_alone_does_not_warn() -> None:
    """A run that kept its deadlines on a busy host is fine: no warning for the steal alone."""
    s = summarize({"sample": "40000", "late_steps": "10", "schedule": "realtime"}, None, [],
                  steal=0.15)
    assert s.warning() is None
