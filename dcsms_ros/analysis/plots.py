"""PNG figures of an analysis (matplotlib, Agg backend: no display needed)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from dcsms_ros.analysis.criteria import CRITERIA


def _pyplot() -> Any:
    import matplotlib

    matplotlib.use("Agg")  # headless CI / ssh; must precede pyplot's import
    import matplotlib.pyplot as plt

    return plt


#: Frequency band of the transmissibility figure, Hz.
F_LO, F_HI = 0.5, 100.0


def plot_transmissibility(path: Path, axis: str, curves: list[dict[str, Any]]) -> Path:
    """Estimated |v_pN/v_b| per mode (solid), analytic (dashed) and coherence below.

    ``curves``: dicts with ``label``, ``f`` (F,), ``h`` (F,) complex, ``coherence`` (F,),
    optional ``averages`` (Welch segments), ``f_an``/``h_an`` (analytic) and ``flagged``
    [(lo, hi), ...] Hz. Bins whose |H1| random error exceeds 10 % are drawn faint: there the
    estimate is scatter from uncorrelated table forces, not the transfer function.
    """
    from dcsms_ros.analysis.estimators import h1_random_error

    plt = _pyplot()
    fig, (ax1, ax2) = plt.subplots(2, 1, sharex=True, figsize=(8, 6.5),
                                   gridspec_kw={"height_ratios": [3, 1]})
    shown: list[np.ndarray] = []  # magnitudes inside the plotted band set the y range
    for i, c in enumerate(curves):
        color = f"C{i}"
        sel = c["f"] > 0
        mag = np.abs(c["h"][sel])
        if c.get("averages"):
            ok = h1_random_error(c["coherence"][sel], c["averages"]) <= 0.1
            ax1.loglog(c["f"][sel], mag, color=color, lw=0.6, alpha=0.3)
            ax1.loglog(c["f"][sel], np.where(ok, mag, np.nan), color=color, label=c["label"])
        else:
            ax1.loglog(c["f"][sel], mag, color=color, label=c["label"])
        shown.append(mag[(c["f"][sel] >= F_LO) & (c["f"][sel] <= F_HI)])
        if c.get("h_an") is not None:
            ax1.loglog(c["f_an"], np.abs(c["h_an"]), "--", color=color, lw=1)
            shown.append(np.abs(c["h_an"])[(c["f_an"] >= F_LO) & (c["f_an"] <= F_HI)])
        for lo, hi in c.get("flagged", []):
            ax1.axvspan(lo, hi, color=color, alpha=0.12)
        ax2.semilogx(c["f"][sel], c["coherence"][sel], color=color)
    ax1.set_ylabel("|v_p/v_b|")
    ax1.set_title(f"Stage transmissibility, axis {axis} (dashed: analytic; faint: random "
                  "error > 10 %; shaded: > 3 dB off)", fontsize=10)
    ax1.grid(True, which="both", alpha=0.3)
    ax1.legend(fontsize=8)
    ax2.set_ylabel("coherence")
    ax2.set_xlabel("frequency (Hz)")
    ax2.set_ylim(0, 1.05)
    ax2.axhline(0.9, color="k", lw=0.5, ls=":")
    ax2.grid(True, which="both", alpha=0.3)
    ax1.set_xlim(F_LO, F_HI)
    vals = np.concatenate(shown) if shown else np.empty(0)
    vals = vals[np.isfinite(vals) & (vals > 0)]
    if vals.size:  # the whole band, without the decades the curves reach only past F_HI
        ax1.set_ylim(vals.min() / 2, vals.max() * 2)
    return _save(plt, fig, path)


def plot_asd(path: Path, axis: str, curves: list[dict[str, Any]]) -> Path:
    """ASD (m/s/sqrt(Hz)) of the last stage per mode; ``curves``: label, f, asd."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(8, 5))
    for c in curves:
        sel = c["f"] > 0
        ax.loglog(c["f"][sel], c["asd"][sel], label=c["label"])
    ax.set_xlim(0.5, 100)
    ax.set_xlabel("frequency (Hz)")
    ax.set_ylabel("velocity ASD (m/s/sqrt(Hz))")
    ax.set_title(f"Top-stage velocity ASD, axis {axis}")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    return _save(plt, fig, path)


def plot_third_octave(path: Path, axis: str, centres: np.ndarray,
                      curves: list[dict[str, Any]]) -> Path:
    """One-third-octave RMS velocity per mode against the VC-A ... VC-G curves."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(8, 5.5))
    for c in curves:
        ax.loglog(centres, np.asarray(c["rms"]) * 1e6, "o-", ms=3, label=c["label"])
    fine = np.geomspace(1, 80, 200)
    for crit in CRITERIA:
        ax.loglog(fine, crit.limit(fine) * 1e6, "k-", lw=0.6, alpha=0.6)
        ax.text(82, crit.velocity_mps * 1e6, crit.name, fontsize=7, va="center")
    ax.set_xlim(0.9, 100)
    ax.set_xlabel("one-third-octave band centre (Hz)")
    ax.set_ylabel("RMS velocity (um/s)")
    ax.set_title(f"Top-stage one-third-octave velocity vs VC curves, axis {axis}")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    return _save(plt, fig, path)


def _save(plt: Any, fig: Any, path: Path) -> Path:
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


__all__ = ["plot_asd", "plot_third_octave", "plot_transmissibility"]
