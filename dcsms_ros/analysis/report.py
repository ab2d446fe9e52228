"""``analyze``: bags -> per-mode transmissibility, Table 4, VC verdicts, forces, report files."""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from dcsms_ros.analysis import estimators as est
from dcsms_ros.analysis import modetable
from dcsms_ros.analysis import paper as paper_table
from dcsms_ros.analysis.criteria import evaluate
from dcsms_ros.analysis.reader import AXIS_NAMES, BagData, Progress, config_from_yaml, read_bag
from dcsms_ros.analysis.segments import MIN_SEGMENT_S, SETTLE_S, Segment, align, split_segments
from dcsms_ros.analysis.stability import envelope
from dcsms_ros.core.config import SystemConfig
from dcsms_ros.core.modes import parse_mode
from dcsms_ros.jsonutil import jsonable

#: Analytic and estimated transmissibility "disagree" beyond this (dB).
DISAGREE_DB = 3.0
#: Bins compared with the analytic model: 1-sigma random error of |H1| at most 10 % (0.8 dB),
#: so a 3 dB disagreement is > 3.5 sigma, not scatter.
MAX_RANDOM_ERROR = 0.1
COMPARE_RANGE_HZ = (0.5, 100.0)
#: An applied force within this fraction of its limit counts as saturated.
SATURATION_FRACTION = 0.999


@dataclass
class Summary:
    """Result of :func:`analyze`; :meth:`to_dict` is what ``summary.json`` holds.

    Attributes
    ----------
    segments : list of dict
        One per analysed mode segment (see ``summary.json``: ``mode``, ``axes.<a>.normalized``,
        ``axes.<a>.attenuation_db``, ``vc``, ``analytic``, ``forces`` ...).
    reference : str
        Label of the reference mode; ``resonance_hz`` its resonance per axis (Hz).
    files : list of str
        Written files (report.md, PNGs, summary.json) when ``out_dir`` was given.
    """

    bags: list[str]
    reference: str
    axes: list[str]
    resonance_hz: dict[str, float] = field(default_factory=dict)
    segments: list[dict[str, Any]] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    config_source: str | None = None
    files: list[str] = field(default_factory=list)
    definition: str = modetable.__doc__ or ""
    #: rows {mode, axis, paper, ours, ratio} against the paper's Table 4, when compared
    paper: list[dict[str, Any]] | None = None

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (no arrays of spectra; those go to the plots)."""
        return jsonable({
            "bags": self.bags, "reference": self.reference, "axes": self.axes,
            "resonance_hz": self.resonance_hz, "config_source": self.config_source,
            "table4_definition": " ".join(self.definition.split()),
            "segments": self.segments, "warnings": self.warnings, "files": self.files,
            "paper_comparison": self.paper,
        })

    def table(self) -> str:
        """The mode table as text (see :func:`modetable.format_table`)."""
        return modetable.format_table(self.segments, self.axes)


def analyze(bags: Sequence[str | Path], reference: str = "passive",
            out_dir: str | Path | None = None, config: SystemConfig | None = None,
            progress: Progress | None = None, settle_s: float = SETTLE_S,
            paper: bool | None = None) -> Summary:
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
    settle_s : float
        Time dropped after every mode switch (s).
    paper : bool, optional
        Compare the mode table with the paper's Table 4 (:mod:`.paper`); default: when the
        configuration is 6-DOF (the paper's table is the three-point TEM in X, Y, Z).

    Raises
    ------
    BagError
        A bag cannot be read (the message names it).
    """
    ref_mode = parse_mode(reference)
    warnings: list[str] = []
    work: list[tuple[BagData, Segment, SystemConfig | None]] = []
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
        ref = next(iter(data.bodies.values()))
        if ref.stamp_ns.size == 0:
            warnings.append(f"{data.path}: no velocity samples")
            continue
        for seg in split_segments(data.modes, int(ref.stamp_ns[0]), int(ref.stamp_ns[-1]),
                                  settle_s):
            work.append((data, seg, cfg))
    axes = _axes(work)
    summary = Summary([str(b) for b in bags], ref_mode.label, axes, warnings=warnings,
                      config_source=cfg_source)
    results = []
    for data, seg, cfg in work:
        r = _segment(data, seg, cfg, axes, summary)
        if r is not None:
            results.append(r)
    _table4(results, ref_mode.label, summary)
    summary.segments = [r["json"] for r in results]
    cfg_any = next((c for _, _, c in work if c is not None), None)
    if paper or (paper is None and cfg_any is not None and cfg_any.plant.dof == 6):
        ours = {s["mode"]: {a: s["axes"][a].get("normalized") for a in axes}
                for s in summary.segments}
        summary.paper = paper_table.comparison(ours, axes)
    if out_dir is not None:
        from dcsms_ros.analysis import output

        output.write_all(Path(out_dir), summary, results)
    return summary


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
             summary: Summary) -> dict[str, Any] | None:
    where = f"{data.path} [{seg.label} @ {seg.switch_ns * 1e-9:.2f} s]"
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
    js: dict[str, Any] = {
        "bag": str(data.path), "mode": seg.label, "t_start_s": seg.t0_ns * 1e-9,
        "t_end_s": seg.t1_ns * 1e-9, "duration_s": seg.duration_s, "fs_hz": al.fs,
        "samples": n, "missing_samples": al.missing, "nperseg": nper,
        "resolution_hz": al.fs / nper, "source": data.source, "axes": {},
    }
    arrays: dict[str, Any] = {}
    for a in axes:
        j = AXIS_NAMES.index(a)
        f, p_top = est.psd(al.bodies[top][:, j], al.fs, nper)
        ax: dict[str, Any] = {"rms_mps": float(np.std(al.bodies[top][:, j], dtype=np.float64))}
        tfs = []
        if "ground" in al.bodies:
            tfs = [est.transfer_h1(al.bodies["ground"][:, j], al.bodies[s][:, j], al.fs, nper)
                   for s in stages]
            peaks = est.find_resonances(tfs[-1].f, np.abs(tfs[-1].h))
            ax["averages"] = tfs[-1].averages
            ax["tf_peaks_hz"] = [p.f_hz for p in peaks]
        ax["asd_peaks_hz"] = [p.f_hz for p in est.find_resonances(f, np.sqrt(p_top), 6.0,
                                                                  max_peaks=3)]
        ax["third_octave_centres_hz"] = bands[:, 0]
        ax["third_octave_rms_mps"] = {}
        ax["vc"] = {}
        for s in stages:
            fs_, p_s = (f, p_top) if s == top else est.psd(al.bodies[s][:, j], al.fs, nper)
            rms = est.band_rms(fs_, p_s, bands)
            v = evaluate(bands[:, 0], rms)
            ax["third_octave_rms_mps"][s] = rms
            ax["vc"][s] = {"best": v.best, "margin_db": v.margin_db,
                           "worst_band_hz": v.worst_band_hz}
        an = _analytic(cfg, seg, a, tfs, summary, where)
        ax["analytic"] = an["json"] if an else None
        js["axes"][a] = ax
        arrays[a] = {"f": f, "psd": p_top, "tfs": tfs, "analytic": an}
    js["forces"] = _forces(data, seg, cfg)
    js["stability"] = _stability(al.bodies, stages, axes, al.fs, summary, where)
    return {"json": js, "arrays": arrays, "top": top}


def _stability(bodies: dict[str, np.ndarray], stages: list[str], axes: list[str], fs: float,
               summary: Summary, where: str) -> dict[str, Any]:
    """Growing envelopes of the stage velocities (:mod:`.stability`): an unstable segment."""
    growing: list[dict[str, Any]] = []
    for s in stages:
        for a in axes:
            env = envelope(bodies[s][:, AXIS_NAMES.index(a)], fs)
            if env is not None and env.growing:
                growing.append({"body": s, "axis": a, "rate_per_s": env.rate_per_s,
                                "factor": env.factor})
    if growing:
        g = max(growing, key=lambda x: float(x["rate_per_s"]))
        summary.warnings.append(f"{where}: UNSTABLE: the {g['body']} {g['axis']} velocity "
                                f"envelope grows {g['rate_per_s']:.3g} /s (x{g['factor']:.1f} "
                                f"over the segment)")
    return {"unstable": bool(growing), "growing": growing}


def _analytic(cfg: SystemConfig | None, seg: Segment, axis: str, tfs: list[est.TransferEstimate],
              summary: Summary, where: str) -> dict[str, Any] | None:
    """Analytic v_pi/v_b on the estimate's grid and the bands where they disagree."""
    if cfg is None or seg.mode is None or not tfs:
        return None
    try:
        from dcsms_ros.core import analytics

        model = analytics.transmissibility(cfg, seg.mode, axis, sensors=cfg.sensors.dynamics)
        est_f = tfs[-1].f
        h_an = [np.asarray(analytics.freq_response(t, est_f)) for t in model]
    except Exception as exc:  # noqa: BLE001 - the overlay is optional; the report must go on
        summary.warnings.append(f"{where}: analytic model unavailable ({type(exc).__name__}: "
                                f"{exc}); no overlay")
        return None
    tf = tfs[-1]
    sel = (tf.f >= COMPARE_RANGE_HZ[0]) & (tf.f <= COMPARE_RANGE_HZ[1])
    with np.errstate(divide="ignore"):
        err = 20 * np.log10(np.abs(tf.h)) - 20 * np.log10(np.abs(h_an[-1]))
    noise = est.h1_random_error(tf.coherence, tf.averages)
    good = sel & (noise <= MAX_RANDOM_ERROR) & np.isfinite(err)
    bad = good & (np.abs(err) > DISAGREE_DB)
    flagged = _runs(tf.f, bad)
    js = {"compared_bins": int(good.sum()),
          "max_abs_error_db": float(np.max(np.abs(err[good]))) if good.any() else None,
          "rms_error_db": float(np.sqrt(np.mean(err[good] ** 2))) if good.any() else None,
          "disagree_bands_hz": flagged}
    return {"json": js, "h": h_an, "flagged": flagged}


def _runs(f: np.ndarray, mask: np.ndarray) -> list[list[float]]:
    """Contiguous runs of ``mask`` as [f_lo, f_hi] (Hz)."""
    idx = np.flatnonzero(mask)
    if idx.size == 0:
        return []
    breaks = np.flatnonzero(np.diff(idx) > 1)
    starts = np.r_[idx[0], idx[breaks + 1]]
    ends = np.r_[idx[breaks], idx[-1]]
    return [[float(f[s]), float(f[e])] for s, e in zip(starts, ends)]


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


def _table4(results: list[dict[str, Any]], ref_label: str, summary: Summary) -> None:
    refs = [r for r in results if r["json"]["mode"].lower() == ref_label.lower()]
    if not refs:
        summary.warnings.append(f"no {ref_label} segment: Table 4 not normalised")
        return
    ref = max(refs, key=lambda r: r["json"]["duration_s"])
    for a in summary.axes:
        f, p = ref["arrays"][a]["f"], ref["arrays"][a]["psd"]
        f_r = modetable.resonance_frequency(f, np.sqrt(p))
        summary.resonance_hz[a] = f_r
        base = modetable.resonance_band_rms(f, p, f_r)
        for r in results:
            arr = r["arrays"][a]
            val = modetable.resonance_band_rms(arr["f"], arr["psd"], f_r)
            norm, db = modetable.normalize(val, base)
            r["json"]["axes"][a].update(resonance_band_rms_mps=val, normalized=norm,
                                        attenuation_db=db)


def dumps(summary: Summary) -> str:
    """``summary.json`` text (strict JSON: non-finite numbers become null)."""
    return json.dumps(summary.to_dict(), indent=1, allow_nan=False)


__all__ = ["Summary", "analyze", "dumps"]
