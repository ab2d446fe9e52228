"""PNG figures of an analysis (matplotlib, Agg backend: no display needed)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from dcsms_ros.analysis.criteria import CRITERIA
from dcsms_ros.analysis.estimators import h1_random_error


def _pyplot() -> Any:
    import matplotlib  # noqa: PLC0415 - deferred: matplotlib only when plotting

    matplotlib.use("Agg")  # headless CI / ssh; must precede pyplot's import
    import matplotlib.pyplot as plt  # noqa: PLC0415 - deferred: matplotlib only when plotting

    return plt


#: Frequency band of the transmissibility figure, Hz.
F_LO, F_HI = 0.5, 100.0


def plot_transmissibility(path: Path, axis: str, curves: list[dict[str, Any]]) -> Path:
    """Estimated |v_pN/v_b| per mode (solid), the loop model (dashed) and coherence below;
    see :func:`plot_frf`."""
    return plot_frf(path, curves, "|v_p/v_b|",
                    f"Stage transmissibility, axis {axis} (dashed: model; faint: random error "
                    "> 10 %; shaded: > 3 dB off)")


def plot_mobility(path: Path, axis: str, curves: list[dict[str, Any]]) -> Path:
    """Estimated mobility |v_pi/F| ((m/s)/N) per excited segment and stage, the loop model
    dashed; see :func:`plot_frf`."""
    return plot_frf(path, curves, "|v_p/F| ((m/s)/N)",
                    f"Mobility from the excitation, axis {axis} (dashed: model; faint: random "
                    "error > 10 %; shaded: > 3 dB off)")


def plot_frf(path: Path, curves: list[dict[str, Any]], ylabel: str, title: str) -> Path:
    """Estimated frequency responses (solid), the model (dashed) and coherence below.

    ``curves``: dicts with ``label``, ``f`` (F,), ``h`` (F,) complex, ``coherence`` (F,),
    optional ``averages`` (Welch segments), ``h_model`` (F,) complex on the same bins (NaN
    where not evaluated) and ``flagged`` [(lo, hi), ...] Hz. Bins whose |H1| random error
    exceeds 10 % are drawn faint: there the estimate is scatter from uncorrelated sources.
    """
    plt = _pyplot()
    fig, (ax1, ax2) = plt.subplots(2, 1, sharex=True, figsize=(8, 6.5),
                                   gridspec_kw={"height_ratios": [3, 1]})
    shown: list[np.ndarray] = []  # magnitudes inside the plotted band set the y range
    for i, c in enumerate(curves):
        color = f"C{i % 10}"
        sel = c["f"] > 0
        f = c["f"][sel]
        mag = np.abs(c["h"][sel])
        if c.get("averages"):
            ok = h1_random_error(c["coherence"][sel], c["averages"]) <= 0.1
            ax1.loglog(f, mag, color=color, lw=0.6, alpha=0.3)
            ax1.loglog(f, np.where(ok, mag, np.nan), color=color, label=c["label"])
        else:
            ax1.loglog(f, mag, color=color, label=c["label"])
        shown.append(mag[(f >= F_LO) & (f <= F_HI)])
        if c.get("h_model") is not None:
            hm = np.abs(np.asarray(c["h_model"])[sel])
            ax1.loglog(f, hm, "--", color=color, lw=1)
            shown.append(hm[(f >= F_LO) & (f <= F_HI)])
        for lo, hi in c.get("flagged", []):
            ax1.axvspan(lo, hi, color=color, alpha=0.12)
        ax2.semilogx(f, c["coherence"][sel], color=color)
    _two_panels(ax1, ax2, ylabel, title, "coherence", (0, 1.05))
    ax2.axhline(0.9, color="k", lw=0.5, ls=":")
    vals = np.concatenate(shown) if shown else np.empty(0)
    vals = vals[np.isfinite(vals) & (vals > 0)]
    if vals.size:  # the whole band, without the decades the curves reach only past F_HI
        ax1.set_ylim(vals.min() / 2, vals.max() * 2)
    return _save(plt, fig, path)


def plot_fit(path: Path, curves: list[dict[str, Any]], ylabel: str, title: str) -> Path:
    """Measured responses against the model at the start (dotted) and fitted (dashed):
    magnitude above, phase (degrees) below.

    ``curves``: dicts with ``label``, ``f`` (F,) Hz, ``h`` (F,) complex measured, ``used``
    (F,) bool (the fitted bins; the others are drawn faint), ``h_start`` and ``h_fit`` (F,)
    complex.
    """
    plt = _pyplot()
    fig, (ax1, ax2) = plt.subplots(2, 1, sharex=True, figsize=(8, 7),
                                   gridspec_kw={"height_ratios": [3, 2]})
    for i, c in enumerate(curves):
        color = f"C{i % 10}"
        f, h, used = c["f"], c["h"], c["used"]
        ax1.loglog(f, np.abs(h), color=color, lw=0.5, alpha=0.25)
        ax1.loglog(f, np.where(used, np.abs(h), np.nan), color=color, lw=1,
                   label=f"{c['label']} measured")
        ax1.loglog(f, np.abs(c["h_start"]), ":", color=color, lw=1)
        ax1.loglog(f, np.abs(c["h_fit"]), "--", color="k" if len(curves) == 1 else color,
                   lw=1)
        ax2.semilogx(f, np.where(used, np.degrees(np.angle(h)), np.nan), color=color, lw=1)
        ax2.semilogx(f, np.degrees(np.angle(c["h_fit"])), "--",
                     color="k" if len(curves) == 1 else color, lw=1)
    _two_panels(ax1, ax2, ylabel, title, "phase (deg)", (-185, 185))
    return _save(plt, fig, path)


def _two_panels(ax1: Any, ax2: Any, ylabel: str, title: str, lower: str,
                lower_ylim: tuple[float, float]) -> None:
    """Labels, grids and the 0.5-100 Hz range of a magnitude panel over a second one."""
    ax1.set_ylabel(ylabel)
    ax1.set_title(title, fontsize=10)
    ax1.grid(True, which="both", alpha=0.3)
    ax1.legend(fontsize=7)
    ax2.set_ylabel(lower)
    ax2.set_xlabel("frequency (Hz)")
    ax2.set_ylim(*lower_ylim)
    ax2.grid(True, which="both", alpha=0.3)
    ax1.set_xlim(F_LO, F_HI)


def _marks(ax: Any, marks: list[tuple[float, str]], spans: list[tuple[float, float]],
           label_y: float | None = None) -> None:
    """Mode switches as labelled vertical lines, excited spans shaded."""
    for t0, t1 in spans:
        ax.axvspan(t0, t1, color="tab:orange", alpha=0.12, lw=0)
    for t, label in marks:
        ax.axvline(t, color="k", lw=0.8, ls="--")
        if label_y is not None:
            ax.text(t, label_y, f" {label}", rotation=90, va="top", ha="left", fontsize=7)


def plot_spectrogram(path: Path, title: str, tf: Any) -> Path:
    """Spectrogram (ASD, dB re 1 m/s/sqrt(Hz)) of a :class:`~.timefreq.TimeFrequency`, log
    frequency 0.5-100 Hz, mode switches marked and excited spans shaded."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(10, 5))
    sel = (tf.f_hz >= F_LO) & (tf.f_hz <= F_HI)
    db = 10 * np.log10(np.maximum(tf.psd[sel].astype(np.float64), 1e-300))
    finite = db[np.isfinite(db) & (db > -290)]
    lo, hi = (np.percentile(finite, [2, 99.8]) if finite.size else (-200.0, -100.0))
    mesh = ax.pcolormesh(tf.t_s, tf.f_hz[sel], db, shading="nearest", cmap="viridis",
                         vmin=lo, vmax=hi)
    ax.set_yscale("log")
    ax.set_ylim(F_LO, F_HI)
    _marks(ax, tf.marks, tf.spans, F_HI * 0.9)
    ax.set_xlabel("time (s from the start of the bag)")
    ax.set_ylabel("frequency (Hz)")
    ax.set_title(title, fontsize=10)
    fig.colorbar(mesh, ax=ax, label="velocity ASD (dB re 1 m/s/sqrt(Hz))")
    return _save(plt, fig, path)


def plot_blrms(path: Path, title: str, tf: Any) -> Path:
    """Band-limited RMS trends (m/s) of a :class:`~.timefreq.TimeFrequency`, one line per band,
    mode switches marked and excited spans shaded."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(10, 4.5))
    for (lo, hi), y in zip(tf.bands, tf.blrms, strict=True):
        ax.semilogy(tf.t_s, y * 1e6, label=f"{lo:g}-{hi:g} Hz")
    top = float(np.nanmax(tf.blrms)) * 1e6 if tf.blrms.size else 1.0
    _marks(ax, tf.marks, tf.spans, top * 1.5)
    ax.set_xlabel("time (s from the start of the bag)")
    ax.set_ylabel("band RMS velocity (um/s)")
    ax.set_title(title, fontsize=10)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
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


__all__ = ["plot_asd", "plot_blrms", "plot_fit", "plot_frf", "plot_mobility",
           "plot_spectrogram", "plot_third_octave", "plot_transmissibility"]
