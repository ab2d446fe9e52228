"""Per segment and axis: the frequency responses a segment can give, and the model beside them.

What a segment can estimate depends on what drove it:

* *transmissibility* v_pi / v_b (Welch H1 from the ground velocity): needs the ground topic; it
  is usable where the ground dominates the stage's motion. Table forces, an excitation or (in
  active modes) the loops' own noise leave few usable bins.
* *mobility* v_pi / F (H1 from the recorded excitation ``/dcsms/force/excitation`` along the
  same axis): needs an excited segment (:func:`.segments.split_excited`); the excitation is
  independent of every disturbance, so the estimate is unbiased, and with a few newtons its
  coherence is high across its band.

A bin is *usable* when the normalised random error of |H1| (Bendat & Piersol,
:func:`.estimators.h1_random_error`) is at most :data:`MAX_RANDOM_ERROR`. Every usable bin in
:data:`COMPARE_RANGE_HZ` is compared with the loop model as the estimator sees it
(:mod:`.modelfrf`), and the count is reported.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from dcsms_ros.analysis import estimators as est
from dcsms_ros.analysis.modelfrf import LoopFrf, as_estimated

#: Bins compared with the model and fitted: 1-sigma random error of |H1| at most 10 %
#: (0.8 dB), so a 3 dB disagreement is > 3.5 sigma, not scatter.
MAX_RANDOM_ERROR = 0.1
#: Model and estimate "disagree" beyond this (dB).
DISAGREE_DB = 3.0
COMPARE_RANGE_HZ = (0.5, 100.0)
#: An estimate is "estimated" when some stage has this fraction of its band bins usable,
#: "partial" with at least :data:`MIN_USABLE_BINS`, else "not estimated".
ESTIMATED_FRACTION = 0.5
MIN_USABLE_BINS = 20
KINDS = ("transmissibility", "mobility")


@dataclass
class Estimate:
    """One kind of response of one segment and axis, for each stage.

    Attributes
    ----------
    kind : str
        ``transmissibility`` (-) or ``mobility`` ((m/s)/N).
    stages : list of str
        Output stages, cascade order.
    tfs : list of TransferEstimate
        One per stage (empty when unavailable).
    source : str
        The input: ``ground.<axis>`` or ``<stage>.<axis>`` (the excited stage).
    reason : str
        Why it is unavailable ("" when available).
    sxx : ndarray, shape (F,) or None
        Auto-spectrum of the input (unit^2/Hz), the model's smoothing weight.
    model : ndarray of complex, shape (F, n_stages), or None
        The loop model on the estimate's bins as the estimator sees it.
    """

    kind: str
    stages: list[str]
    tfs: list[est.TransferEstimate] = field(default_factory=list)
    source: str = ""
    reason: str = ""
    sxx: np.ndarray | None = None
    model: np.ndarray | None = None
    nperseg: int = 0
    fs: float = 0.0

    @property
    def available(self) -> bool:
        return bool(self.tfs)

    def usable(self, i: int) -> np.ndarray:
        """Mask of the usable bins of stage ``i`` inside :data:`COMPARE_RANGE_HZ`, shape (F,)."""
        t = self.tfs[i]
        band = (t.f >= COMPARE_RANGE_HZ[0]) & (t.f <= COMPARE_RANGE_HZ[1])
        return band & (est.h1_random_error(t.coherence, t.averages) <= MAX_RANDOM_ERROR)

    def band_bins(self) -> int:
        f = self.tfs[0].f
        return int(np.count_nonzero((f >= COMPARE_RANGE_HZ[0]) & (f <= COMPARE_RANGE_HZ[1])))

    def verdict(self) -> dict[str, Any]:
        """``status`` (estimated / partial / not estimated / unavailable), usable bins per
        stage and the band's bin count, as JSON."""
        if not self.available:
            return {"status": "unavailable", "source": self.source, "reason": self.reason}
        usable = {s: int(np.count_nonzero(self.usable(i))) for i, s in enumerate(self.stages)}
        n = self.band_bins()
        best = max(usable.values())
        status = ("estimated" if best >= ESTIMATED_FRACTION * n else
                  "partial" if best >= MIN_USABLE_BINS else "not estimated")
        return {"status": status, "source": self.source, "usable_bins": usable,
                "band_bins": n, "band_hz": list(COMPARE_RANGE_HZ),
                "averages": self.tfs[0].averages}

    def compare(self) -> dict[str, Any] | None:
        """Model against estimate on every usable bin, per stage (None without a model)."""
        if self.model is None or not self.available:
            return None
        out: dict[str, Any] = {}
        for i, s in enumerate(self.stages):
            t = self.tfs[i]
            with np.errstate(divide="ignore", invalid="ignore"):
                err = 20 * np.log10(np.abs(t.h) / np.abs(self.model[:, i]))
            good = self.usable(i) & np.isfinite(err)
            bad = good & (np.abs(err) > DISAGREE_DB)
            out[s] = {"compared_bins": int(good.sum()), "band_bins": self.band_bins(),
                      "max_abs_error_db": float(np.max(np.abs(err[good]))) if good.any()
                      else None,
                      "rms_error_db": float(np.sqrt(np.mean(err[good] ** 2))) if good.any()
                      else None,
                      "disagree_bands_hz": runs(t.f, bad)}
        return out


def runs(f: np.ndarray, mask: np.ndarray) -> list[list[float]]:
    """Contiguous runs of ``mask`` as [f_lo, f_hi] (Hz)."""
    idx = np.flatnonzero(mask)
    if idx.size == 0:
        return []
    breaks = np.flatnonzero(np.diff(idx) > 1)
    starts = np.r_[idx[0], idx[breaks + 1]]
    ends = np.r_[idx[breaks], idx[-1]]
    return [[float(f[s]), float(f[e])] for s, e in zip(starts, ends, strict=True)]


def excited_axes(excitation: np.ndarray | None, axes: Sequence[str]) -> list[str]:
    """Translation axes among ``axes`` whose excitation column (K, 6) is not all zero."""
    if excitation is None:
        return []
    return [a for a in axes if np.any(excitation[:, "xyz".index(a)] != 0.0)]


def estimate(kind: str, x: np.ndarray | None, outputs: dict[str, np.ndarray], axis: str,
             fs: float, nperseg: int, source: str, reason: str) -> Estimate:
    """H1 of each output over ``x`` along ``axis`` (None: unavailable, with ``reason``).

    Parameters
    ----------
    kind : str
        One of :data:`KINDS`.
    x : ndarray, shape (K,) or None
        Input record (m/s or N).
    outputs : dict of stage name to ndarray, shape (K, 3)
        Stage velocities x y z (m/s), cascade order.
    axis : str
        ``x``, ``y`` or ``z``.
    fs : float
        Sample rate, Hz.
    nperseg : int
        Welch segment length.
    """
    e = Estimate(kind, list(outputs), source=source, reason=reason, nperseg=nperseg, fs=fs)
    if x is None:
        return e
    j = "xyz".index(axis)
    e.tfs = [est.transfer_h1(x, v[:, j], fs, nperseg) for v in outputs.values()]
    _, e.sxx = est.psd(x, fs, nperseg)
    return e


def attach_model(e: Estimate, frf: LoopFrf, axis: str, excited_stage: int = 0) -> None:
    """Set ``e.model``: the loop model on the estimate's bins inside the compare range (NaN
    outside), as the Welch estimator sees it (smoothed by its window kernel, weighted by the
    input's spectrum)."""
    if not e.available:
        return
    f = e.tfs[0].f
    sel = (f >= COMPARE_RANGE_HZ[0]) & (f <= COMPARE_RANGE_HZ[1])
    stages = [int(s[5:]) for s in e.stages]
    if e.kind == "mobility":
        def resp(ff: np.ndarray) -> np.ndarray:
            return frf.mobility(ff, excited_stage, axis, stages)
    else:
        def resp(ff: np.ndarray) -> np.ndarray:
            return frf.transmissibility(ff, axis, stages)
    model = np.full((f.size, len(stages)), np.nan + 0j)
    sxx = None if e.sxx is None else e.sxx[sel]
    model[sel] = as_estimated(resp, f[sel], e.fs, e.nperseg, sxx)
    e.model = model


__all__ = ["COMPARE_RANGE_HZ", "DISAGREE_DB", "KINDS", "MAX_RANDOM_ERROR", "Estimate",
           "attach_model", "estimate", "excited_axes", "runs"]
