"""``analyze``: bags -> per-mode transmissibility, Table 4, VC verdicts, forces, report files."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from dcsms_ros.analysis import estimators as est
from dcsms_ros.analysis import frf, output, segment_stability, timefreq
from dcsms_ros.analysis import paper as paper_table
from dcsms_ros.analysis import timeline as tline
from dcsms_ros.analysis.criteria import evaluate
from dcsms_ros.analysis.modelfrf import LoopFrf
from dcsms_ros.analysis.reader import BagData, Progress, config_from_yaml, read_bag
from dcsms_ros.analysis.segments import (
    MIN_SEGMENT_S,
    SETTLE_S,
    Segment,
    align,
    split_excited,
    split_segments,
)
from dcsms_ros.analysis.series import AXIS_NAMES
from dcsms_ros.analysis.summary import Summary, dumps
from dcsms_ros.analysis.table4 import table4
from dcsms_ros.analysis.transients import settle_times
from dcsms_ros.core.check import Stability, stability
from dcsms_ros.core.config import SystemConfig
from dcsms_ros.core.modes import ALL_MODES, parse_mode
from dcsms_ros.errors import DcsmsError

#: An applied force within this fraction of its limit counts as saturated.
SATURATION_FRACTION = 0.999


def analyze(bags: Sequence[str | Path], reference: str = "passive",
            out_dir: str | Path | None = None, config: SystemConfig | None = None,
            progress: Progress | None = None,
            settle_s: float | Mapping[str, float] | None = None, from_rest: bool = False,
            export: str | None = None,
            blrms_bands: Sequence[tuple[float, float]] = timefreq.DEFAULT_BANDS,
            paper: bool | None = None, timeline_s: float = tline.WINDOW_S) -> Summary:
    """Analyse one or more DCSMS bags mode by mode.

    Parameters
    ----------
    bags : sequence of path
        rosbag2 directories; segments of all bags are pooled (one bag per mode works too).
    reference : str
        Mode every segment is normalised to (Table 4), default Passive.
    out_dir : path, optional
        Write ``report.md``, PNG figures and ``summary.json`` there (created).
    config : SystemConfig, optional
        Overrides the configuration recorded on ``/dcsms/config``.
    progress : callable(done, total), optional
        Reading progress per bag.
    settle_s : float or mapping of mode label to float, optional
        Time dropped after every mode switch (s), or after a switch into each mode; default:
        per mode, until the transient has decayed in the analysed band by the recorded
        configuration's model (:func:`.transients.settle_times`), :data:`.segments.SETTLE_S`
        without one.
    from_rest : bool
        The bags start from rest (simulations): the first segment loses the settle time too.
    export : str, optional
        Also write every segment's spectra as ``npz``, ``csv`` or ``mat`` tables into
        ``out_dir`` (:mod:`.tables`).
    blrms_bands : sequence of (lo, hi)
        Bands (Hz) of the band-limited RMS trends and of each segment's ``blrms_mps``.
    paper : bool, optional
        Compare the mode table with the paper's Table 4 (:mod:`.paper`); default: when the
        configuration is 6-DOF (the paper's table is the three-point TEM in X, Y, Z).
    timeline_s : float
        Window of the timeline rows (:mod:`.timeline`) of a bag with supervisor transitions
        or mode switches, s (> 0).

    Raises
    ------
    BagError
        A bag cannot be read (the message names it).
    DcsmsError
        A settle time that is negative or not finite, or a timeline window that is not
        positive.
    """
    ref_mode = parse_mode(reference)
    if not timeline_s > 0.0:
        raise DcsmsError(f"timeline window {timeline_s:g} s: must be > 0")
    for x in ((settle_s,) if isinstance(settle_s, (int, float)) else
              () if settle_s is None else tuple(settle_s.values())):
        # a negative settle would analyse the previous mode's samples as this one's
        if not (math.isfinite(x) and x >= 0.0):
            raise DcsmsError(f"settle {x:g} s: must be finite and >= 0")
    warnings: list[str] = []
    work: list[tuple[BagData, Segment, SystemConfig | None]] = []
    timelines: list[tuple[str, tline.Timeline]] = []
    cfg_source = None
    for b in bags:
        data = read_bag(b, progress)
        warnings += [f"{data.path}: {w}" for w in data.warnings]
        cfg = config
        if cfg is None and data.config_text:
            cfg = config_from_yaml(data.config_text, f"{data.path}:/dcsms/config")
        if cfg is None:
            warnings.append(f"{data.path}: no /dcsms/config and no --config: no analytic "
                            "overlay; force limits from the defaults")
        cfg_source = cfg_source or (cfg.source if cfg else None)
        tl = _timeline(data, cfg, timeline_s, warnings)
        if tl is not None:
            timelines.append((str(data.path), tl))
        ref = next(iter(data.bodies.values()))
        if ref.stamp_ns.size == 0:
            warnings.append(f"{data.path}: no velocity samples")
            continue
        settle: float | Mapping[str, float] = settle_s if settle_s is not None else SETTLE_S
        if settle_s is None and cfg is not None:
            settle = {k: v[0] for k, v in settle_times(cfg, ALL_MODES).items()}
        segs = split_segments(data.modes, int(ref.stamp_ns[0]), int(ref.stamp_ns[-1]), settle,
                              from_rest)
        work.extend((data, seg, cfg) for seg in split_excited(segs, data.excitation, settle))
    axes = _axes(work)
    summary = Summary([str(b) for b in bags], ref_mode.label, axes, warnings=warnings,
                      config_source=cfg_source, blrms_bands_hz=[list(b) for b in blrms_bands],
                      timelines=timelines)
    results = []
    models: dict[Any, LoopFrf | None] = {}
    verdicts: dict[Any, Stability] = {}
    for data, seg, cfg in work:
        r = _segment(data, seg, cfg, axes, summary, models, verdicts)
        if r is not None:
            results.append(r)
    table4(results, ref_mode.label, summary)
    summary.segments = [r["json"] for r in results]
    cfg_any = next((c for _, _, c in work if c is not None), None)
    if paper or (paper is None and cfg_any is not None and cfg_any.plant.dof == 6):
        ours = {s["mode"]: {a: s["axes"][a].get("normalized") for a in axes}
                for s in summary.segments}
        summary.paper = paper_table.comparison(ours, axes)
    if out_dir is not None:
        summary.timefreq = _timefreq(work, axes, blrms_bands, summary)
        output.write_all(Path(out_dir), summary, results, export)
    return summary


def _timeline(data: BagData, cfg: SystemConfig | None, window_s: float,
              warnings: list[str]) -> tline.Timeline | None:
    """The bag's timeline when it has supervisor transitions or mode switches (None
    otherwise, or without a configuration: its trip band and force limits are the scale)."""
    if not data.states and len(data.modes) < 2:
        return None
    if cfg is None:
        warnings.append(f"{data.path}: no timeline without a configuration (the trip band "
                        "and the force limits come from it)")
        return None
    tl = tline.build(data, cfg, window_s)
    if tl is not None:
        warnings.extend(tl.warnings)
    return tl


def _axes(work: list[tuple[BagData, Segment, SystemConfig | None]]) -> list[str]:
    cfg = next((c for _, _, c in work if c is not None), None)
    if cfg is not None:
        return ["z"] if cfg.plant.dof == 1 else list(AXIS_NAMES)
    if not work:
        return ["z"]
    last = work[0][0].bodies[max(b for b in work[0][0].bodies if b != "ground")]
    moving = [a for j, a in enumerate(AXIS_NAMES) if np.any(last.values[:, j] != 0)]
    return moving or ["z"]


def _segment(data: BagData, seg: Segment, cfg: SystemConfig | None, axes: list[str],
             summary: Summary, models: dict[Any, LoopFrf | None],
             verdicts: dict[Any, Stability]) -> dict[str, Any] | None:
    where = (f"{data.path} [{seg.label}{' excited' if seg.excited else ''} @ "
             f"{seg.t0_ns * 1e-9:.2f} s]")
    if seg.duration_s < MIN_SEGMENT_S:
        summary.warnings.append(f"{where}: only {seg.duration_s:.1f} s after settling; skipped")
        return None
    al = align(data, seg)
    n = al.stamp_ns.size
    if n < 64 or al.fs <= 0:
        summary.warnings.append(f"{where}: too few common samples ({n}); skipped")
        return None
    if al.missing > 0.001 * n:
        summary.warnings.append(f"{where}: {al.missing} samples missing (drops); spectra "
                                "treat the record as uniformly sampled")
    stages = sorted((b for b in al.bodies if b != "ground"), key=lambda s: int(s[5:]))
    top = stages[-1]
    nper = est.choose_nperseg(al.fs, n)
    bands = est.third_octave_bands(1.0, 80.0)
    exc_stage = _excited_stage(data) if seg.excited else 0
    exc_axes = frf.excited_axes(al.excitation, axes)
    label = seg.label + (f" + excitation {data.excitation.frame_id if data.excitation else ''}."
                         + "".join(exc_axes) if seg.excited else "")
    js: dict[str, Any] = {
        "bag": str(data.path), "mode": seg.label, "segment": label,
        "excited": ({"stage": f"stage{exc_stage}", "axes": exc_axes} if seg.excited else None),
        "t_start_s": seg.t0_ns * 1e-9, "settled_s": (seg.t0_ns - seg.switch_ns) * 1e-9,
        "t_end_s": seg.t1_ns * 1e-9, "duration_s": seg.duration_s, "fs_hz": al.fs,
        "samples": n, "missing_samples": al.missing, "nperseg": nper,
        "resolution_hz": al.fs / nper, "source": data.source, "axes": {},
    }
    model = _model(cfg, seg, data.source, models, summary, where)
    outputs = {s: al.bodies[s] for s in stages}
    arrays: dict[str, Any] = {}
    for a in axes:
        j = AXIS_NAMES.index(a)
        f, p_top = est.psd(al.bodies[top][:, j], al.fs, nper)
        ax: dict[str, Any] = {"rms_mps": float(np.std(al.bodies[top][:, j], dtype=np.float64))}
        ground = al.bodies["ground"][:, j] if "ground" in al.bodies else None
        trans = frf.estimate("transmissibility", ground, outputs, a, al.fs, nper, f"ground.{a}",
                             "no ground velocity topic")
        force = (al.excitation[:, j] if al.excitation is not None and a in exc_axes else None)
        mob = frf.estimate("mobility", force, outputs, a, al.fs, nper,
                           f"stage{exc_stage}.{a}" if force is not None else "",
                           "not excited along this axis" if seg.excited else "not excited")
        if trans.available:
            peaks = est.find_resonances(trans.tfs[-1].f, np.abs(trans.tfs[-1].h))
            ax["averages"] = trans.tfs[-1].averages
            ax["tf_peaks_hz"] = [p.f_hz for p in peaks]
        ax["asd_peaks_hz"] = [p.f_hz for p in est.find_resonances(f, np.sqrt(p_top), 6.0,
                                                                  max_peaks=3)]
        ax["blrms_mps"] = est.band_rms(f, p_top, np.array(
            [[np.sqrt(lo * hi), lo, hi] for lo, hi in summary.blrms_bands_hz]))
        ax["third_octave_centres_hz"] = bands[:, 0]
        ax["third_octave_rms_mps"] = {}
        ax["vc"] = {}
        psds = {b: p_top if b == top else est.psd(al.bodies[b][:, j], al.fs, nper)[1]
                for b in al.bodies}
        for s in stages:
            rms = est.band_rms(f, psds[s], bands)
            v = evaluate(bands[:, 0], rms)
            ax["third_octave_rms_mps"][s] = rms
            ax["vc"][s] = {"best": v.best, "margin_db": v.margin_db,
                           "worst_band_hz": v.worst_band_hz}
        ests = {"transmissibility": trans, "mobility": mob}
        ax["estimates"] = {k: e.verdict() for k, e in ests.items()}
        ax["model"] = {}
        for k, e in ests.items():
            if model is not None and e.available:
                frf.attach_model(e, model, a, exc_stage)
            ax["model"][k] = e.compare()
        js["axes"][a] = ax
        arrays[a] = {"f": f, "psd": p_top, "tfs": trans.tfs, "estimates": ests,
                     "psd_bodies": psds, "top": al.bodies[top][:, j]}
        if ground is not None:
            arrays[a]["ground"] = ground
    js["forces"] = _forces(data, seg, cfg)
    js["stability"] = (segment_stability.judge(al.bodies, stages, axes, al.fs, summary.warnings,
                                               where, _model_stability(cfg, seg, verdicts))
                       if seg.mode is None or seg.mode.feedback else
                       {"unstable": False, "growing": [], "wander": [], "checked": False,
                        "model": None})
    return {"json": js, "arrays": arrays, "top": top}


def _model_stability(cfg: SystemConfig | None, seg: Segment,
                     verdicts: dict[Any, Stability]) -> Stability | None:
    """The loop model's verdict on the segment's mode (cached per configuration and mode)."""
    if cfg is None or seg.mode is None:
        return None
    key = (id(cfg), seg.mode)
    if key not in verdicts:
        verdicts[key] = stability(cfg, seg.mode)
    return verdicts[key]


def _timefreq(work: list[tuple[BagData, Segment, SystemConfig | None]], axes: list[str],
              bands: Sequence[tuple[float, float]], summary: Summary
              ) -> list[tuple[int, str, timefreq.TimeFrequency]]:
    """Spectrogram and BLRMS of each bag's top stage per axis over the whole bag, with the
    mode switches and the excited segments (s from the bag's first sample)."""
    out: list[tuple[int, str, timefreq.TimeFrequency]] = []
    bags: list[BagData] = []
    for data, _, _ in work:
        if all(d is not data for d in bags):
            bags.append(data)
    for i, data in enumerate(bags):
        top = max((b for b in data.bodies if b != "ground"), key=lambda s: int(s[5:]))
        series = data.bodies[top]
        st = series.stamp_ns
        if st.size < 64:
            continue
        t0 = int(st[0])
        fs = 1e9 / float(np.median(np.diff(st)))
        marks = [((ev.stamp_ns - t0) * 1e-9, ev.label) for ev in data.modes]
        spans = [((seg.t0_ns - t0) * 1e-9, (seg.t1_ns - t0) * 1e-9)
                 for d, seg, _ in work if d is data and seg.excited]
        for a in axes:
            try:
                tf = timefreq.compute(series.values[:, AXIS_NAMES.index(a)], fs, bands)
            except DcsmsError as exc:
                summary.warnings.append(f"{data.path}: no time-frequency view: {exc}")
                break
            tf.marks, tf.spans = marks, spans
            out.append((i, a, tf))
    return out


def _excited_stage(data: BagData) -> int:
    """The stage (1-based) named by the excitation's frame_id (1 when it names none)."""
    frame = data.excitation.frame_id if data.excitation is not None else ""
    return int(frame[5:]) if frame.startswith("stage") and frame[5:].isdigit() else 1


def _model(cfg: SystemConfig | None, seg: Segment, source: str,
           models: dict[Any, LoopFrf | None], summary: Summary, where: str) -> LoopFrf | None:
    """The discrete loop model of the segment's mode (cached per configuration and mode)."""
    if cfg is None or seg.mode is None:
        return None
    key = (id(cfg), seg.mode, source)
    if key not in models:
        try:
            models[key] = LoopFrf(cfg, seg.mode, truth=source == "truth")
        except Exception as exc:  # noqa: BLE001 - the overlay is optional; the report goes on
            summary.warnings.append(f"{where}: loop model unavailable ({type(exc).__name__}: "
                                    f"{exc}); no model overlay")
            models[key] = None
    return models[key]


def _forces(data: BagData, seg: Segment, cfg: SystemConfig | None) -> list[dict[str, Any]]:
    """RMS, peak and saturation count of each applied-force channel in the segment."""
    if data.applied is None or data.applied.values.size == 0:
        return []
    s = data.applied
    i0, i1 = np.searchsorted(s.stamp_ns, [seg.t0_ns, seg.t1_ns])  # stamps are sorted
    vals = s.values[i0:i1]  # a view: one channel at a time is widened to float64
    out = []
    for c in range(vals.shape[1]):
        name = s.columns[c] if c < len(s.columns) else f"ch{c}"
        limit = _force_limit(cfg, name, c, vals.shape[1])
        x = vals[:, c].astype(np.float64)
        out.append({
            "channel": name, "rms_n": float(np.sqrt(np.mean(x ** 2))) if x.size else None,
            "peak_n": float(np.max(np.abs(x))) if x.size else None, "limit_n": limit,
            "saturated_samples": int(np.sum(np.abs(x) >= SATURATION_FRACTION * limit)),
            "samples": int(x.size)})
    return out


def _force_limit(cfg: SystemConfig | None, name: str, index: int, channels: int) -> float:
    """Limit (N) of one applied-force channel: per voice coil in 6dof, the stage's lumped
    channel (actuator count x limit) in 1dof."""
    per = cfg.actuators.force_limit_n if cfg else 100.0
    if cfg is None or cfg.plant.dof != 1:
        return per
    stages = cfg.plant.stages
    k = next((i for i, st in enumerate(stages) if st.name in name), None)
    if k is None and channels == len(stages):
        k = index  # one lumped channel per stage, in cascade order
    return per * (stages[k].actuator_count if k is not None else 1)


__all__ = ["Summary", "analyze", "dumps"]
