"""kill -9 of a controller in a real-time graph: its force is zero within 20 ms, then it rejoins."""

from __future__ import annotations

import numpy as np
import pytest
from rel_harness import Graph, Jitter, Probe, assert_clean, mono_ns, report

from dcsms_ros.core.modes import Mode

#: The plant must apply zero force from a dead controller this soon after the kill, s.
SAFE_WITHIN_S = 0.020
# victim -> (mode, its actuator, the other stage's actuator, a loop sharing its stage or None)
CASES = {
    "fb_stage1": (Mode.DFBC, 0, 1, None),
    "fb_stage2": (Mode.DFBC_FFC, 1, 0, None),
    "ff_stage1": (Mode.FFC, 0, 1, None),
}
NS = 1_000_000_000


def _series(probe: Probe, act: int, k0: int, k1: int, rate: float) -> tuple[np.ndarray, np.ndarray]:
    """(sample index, force) of one actuator for samples k0 <= k < k1, in stamp order."""
    with probe.lock:
        rows = [(int(round(ns * rate / NS)), f[act]) for _, ns, f in probe.applied]
    rows = sorted(r for r in rows if k0 <= r[0] < k1)
    arr = np.array(rows, dtype=float).reshape(-1, 2)
    return arr[:, 0].astype(int), arr[:, 1]


def _first_force(probe: Probe, act: int, k0: int, rate: float) -> int | None:
    """Sample index of the first non-zero applied force of ``act`` at or after ``k0``."""
    k, f = _series(probe, act, k0, 1 << 62, rate)
    nz = np.flatnonzero(f != 0.0)
    return int(k[nz[0]]) if len(nz) else None


def _leading_run(f: np.ndarray) -> np.ndarray:
    """``f`` up to its first zero after the first non-zero force. A stall right after the rejoin
    (the new process's forces reaching the plant late: 8 of 31 local rejoins, 12-72 stale
    samples in the first 100 ms) zeroes the force while the fade runs on by the stamps, so the
    force resumes at the gain the fade has reached by then; that is the watchdog answering a
    stall, as later in the run, not the rejoin kicking (CI attempts failed so: first 50 ms at
    0.31-0.37 x the RMS at 0.5 s)."""
    nz = np.flatnonzero(f != 0.0)
    if not len(nz):
        return f
    gap = np.flatnonzero(f[nz[0]:] == 0.0)
    return f[:nz[0] + gap[0]] if len(gap) else f


def _max_step(k: np.ndarray, f: np.ndarray) -> float:
    """Largest change between consecutive samples (gaps, e.g. overruns, skipped), leaving out
    a step into or out of a stale zero after the first force: the plant zeroing a force that
    came too late (the watchdog) is not the controller kicking. The step from zero to the
    first force counts (that is what a kick on rejoining would be). A CI attempt failed on
    such a step with 132 of the 200 reference samples stale (the shared box stalled)."""
    ok = np.diff(k) == 1
    ok[1:] &= (f[1:-1] != 0.0) & (f[2:] != 0.0)
    return float(np.abs(np.diff(f))[ok].max()) if ok.any() else 0.0


# Multi-process timing on a shared 2-core machine: a scheduling hiccup can miss a bound
# once; two reruns keep CI meaningful (every attempt must fail for a red run).
@pytest.mark.flaky(reruns=2, reruns_delay=2)
@pytest.mark.parametrize("victim", sorted(CASES))
def test_killed_controller_is_zeroed_then_rejoins_without_kick(victim, ctx, cfg, tmp_path):
    """kill -9 of a controller: zero force within 20 ms, degraded reported, no kick on restart."""
    mode, act, other, sharer = CASES[victim]
    rate = cfg.plant.rate_hz
    probe = Probe(ctx, forces=(sharer,) if sharer else ())
    jitter = Jitter()
    graph = Graph(cfg, tmp_path, mode=mode)
    try:
        state = f"plant_simulator/{victim}"
        probe.wait(lambda: float(probe.value("plant_simulator", "sim_time_s", "0")) > 2.0,
                   90.0, "plant running for 2 s of simulated time")
        probe.wait(lambda: probe.value(victim, "gain") == "1.000", 10.0, f"{victim} faded in")
        others = [c for c in CASES if c != victim]
        counts0 = {c: int(probe.value(c, "samples", "0")) for c in others}
        t_kill = graph.kill(victim)
        after = t_kill + 50_000_000  # a report made after the kill (+50 ms)
        probe.wait(lambda: (probe.status_after(state, after) or ("",))[0] == "stale", 10.0,
                   f"the plant marks {victim} stale")
        probe.wait(lambda: victim in probe.diag_msgs.get("plant_simulator", "")
                   and "degraded" in probe.diag_msgs["plant_simulator"], 5.0,
                   "plant diagnostics report the degraded state")
        # already stale when killed (a load spike): its force was zero from before the kill
        latency_s = max(0, int(probe.status_after(state, after)[1]["stale_at_mono_ns"])
                        - t_kill) / 1e9
        plant = dict(probe.diag["plant_simulator"])
        # twice the test thread's overrun: the busy node processes wake later than it does
        load = 2 * jitter.worst(t_kill - 50_000_000, t_kill + int(latency_s * 1e9) + 50_000_000)
        k_stale = int(probe.value(state, "stale_at_sample"))
        degraded_msg = probe.diag_msgs["plant_simulator"]
        probe.wait(lambda: probe.applied_reaches(k_stale + 2000, rate), 30.0,
                   "the plant runs on for 1 s after the fault")
        k_before, f_before = _series(probe, act, k_stale - 3000, k_stale, rate)
        _, f_after = _series(probe, act, k_stale, k_stale + 2000, rate)
        _, f_other = _series(probe, other, k_stale, k_stale + 2000, rate)
        assert len(f_before) > 200, f"probe got {len(f_before)} of 3000 samples before"
        assert np.abs(f_before).max() > 0.0, "no force before the kill"
        assert len(f_after) > 200, f"probe got {len(f_after)} of 2000 samples after"
        if sharer is None:
            assert np.all(f_after == 0.0), f"{victim}'s force still applied after stale"
        else:  # the stage's force is now exactly the other loop's command
            with probe.lock:
                allowed = {f[2] for _, _, f in probe.forces[sharer]}
            assert all(x in allowed for x in f_after), f"{victim}'s force still applied"
        if mode != Mode.FFC:  # the other stage's loop is on: its force is still applied
            assert np.abs(f_other).max() > 0.0, "the other loops stopped"
        # their own reports made after the kill (1 Hz: the cached ones may predate it)
        probe.wait(lambda: all(probe.status_after(c, after) for c in others), 5.0,
                   "reports of the other loops after the kill")
        moved = {c: int(probe.status_after(c, after)[1]["samples"]) - n
                 for c, n in counts0.items()}
        assert all(v > 0 for v in moved.values()), f"the other loops stopped: {moved}"
        steady = _max_step(k_before[:-40], f_before[:-40])
        # restart with the same command line (enabled: true): it must fade in, not kick
        t_restart = mono_ns()
        graph.start(victim)
        # the new process's own report: the killed one's last also said gain 1.000
        probe.wait(lambda: probe.seen_after(state, t_restart, "ok")
                   and (probe.status_after(victim, t_restart) or ("", {}))[1].get("gain")
                   == "1.000", 60.0, f"{victim} rejoined")
        k_end = int(probe.value("plant_simulator", "sample"))  # may predate the rejoin
        if sharer is None:  # 1 s past its first applied force: covers 0.45-1 s
            probe.wait(lambda: _first_force(probe, act, k_stale + 2000, rate) is not None,
                       30.0, f"a force of {victim} applied")
            k_end = max(k_end, _first_force(probe, act, k_stale + 2000, rate) + int(1.0 * rate))
        probe.wait(lambda: probe.applied_reaches(k_end, rate), 30.0, "probe caught up")
        k_re, f_re = _series(probe, act, k_stale + 2000, k_end, rate)
        if sharer is None:
            first = int(np.flatnonzero(f_re != 0.0)[0])
            k_re, f_re = k_re[max(first - 1, 0):], f_re[max(first - 1, 0):]
        # the force after it rejoined against itself once faded in (0.5-1 s; non-zero samples:
        # a stall of the shared box past the 10 ms input timeout zeroes the force for a while,
        # the watchdog doing its job): self-normalised, so a state the fault left excited does
        # not count as a kick. The reference spans a second, not 0.45-0.55 s: the force is a
        # 0.5-3.5 Hz signal, and over 100 ms its RMS is one draw of its phase (31 local rejoins
        # of fb_stage2: first 50 ms at 0-0.197 x that, 0-0.108 x the 0.5-1 s RMS; 8 more of
        # each victim: 0-0.194)
        age = k_re - k_re[0]
        ref = f_re[(age >= 0.5 * rate) & (age < 1.0 * rate) & (f_re != 0.0)]
        stale_zeros = int(np.sum((age >= 0.5 * rate) & (age < 1.0 * rate) & (f_re == 0.0)))
        ref_rms = float(np.sqrt(np.mean(ref**2))) if len(ref) else 0.0
        head = _leading_run(f_re[age < 0.05 * rate])
        ramp = float(np.sqrt(np.mean(head**2))) / max(ref_rms, 1e-12)
        early = age < 0.1 * rate
        rejoin_step = _max_step(k_re[early], f_re[early])  # steps while it fades in
        late_max = float(np.abs(ref).max()) if len(ref) else 0.0
        full = float(np.abs(f_before).max())
    finally:
        codes = graph.stop()
        probe.close()
        jitter.close()
    report(f"1-{victim}", f"kill -9 {victim} (real time, {mode.label})",
           f"zero force after {latency_s * 1e3:.1f} ms; '{degraded_msg}'; restart fades in",
           f"{latency_s * 1e3:.1f} ms to zero force (scheduling delay {load * 1e3:.1f} ms); "
           f"rejoin max step {rejoin_step:.3g} N "
           f"(|F| {late_max:.3g} N at 0.5-1 s); first 50 ms at {ramp:.0%} of the RMS at 0.5-1 s"
           + (f" ({stale_zeros} stale-zero samples at 0.5-1 s)" if stale_zeros else ""),
           latency_s=latency_s, rejoin_step_n=rejoin_step, steady_step_n=steady, max_force_n=full,
           ramp_ratio=ramp, sched_delay_s=load, plant_rate_hz=plant["achieved_rate_hz"],
           overruns=plant["overruns"])
    assert latency_s <= SAFE_WITHIN_S + load, (f"force zeroed only after {latency_s * 1e3:.1f} "
                                               f"ms (scheduling delay {load * 1e3:.1f} ms)")
    assert all(c == 0 for n, c in codes.items() if n != victim), codes
    assert_clean(graph.logs())
    # no kick: the force ramps (fade-in over control.fade_time_s = 0.5 s: its first 50 ms carry
    # ~6 % of the RMS once faded in, a full-gain restart ~60 %, median of the 31 rejoins
    # above) and no step in its first 100 ms reaches 30 % of the force it has at 0.5-1 s (a
    # kick is a step of the whole force)
    assert len(ref) > 200, (f"{victim} rejoin: only {len(ref)} non-zero applied-force "
                            "samples 0.5-1 s after it rejoined")
    assert ramp <= 0.3 and rejoin_step <= 0.3 * late_max, (
        f"{victim} rejoin kicked: first 50 ms at {ramp:.3g} x the RMS at 0.5-1 s (bound 0.3), "
        f"max step {rejoin_step:.3g} N vs |F| {late_max:.3g} N at 0.5-1 s")
