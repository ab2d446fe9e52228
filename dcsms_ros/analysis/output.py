"""Write an analysis to disk: ``report.md``, PNG figures and ``summary.json``."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from dcsms_ros.analysis import modetable, plots
from dcsms_ros.analysis.paper import CITATION, within
from dcsms_ros.analysis.summary import Summary, dumps
from dcsms_ros.analysis.tables import write_spectra
from dcsms_ros.errors import DcsmsError


def write_all(out: Path, summary: Summary, results: list[dict[str, Any]],
              export: str | None = None) -> None:
    """Write every output file into ``out`` (created) and list them in ``summary.files``;
    ``export`` adds the spectra tables in that format (:mod:`.tables`)."""
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise DcsmsError(f"{out}: cannot create output directory: {exc.strerror}") from None
    files = []
    for a in summary.axes:
        files += _figures(out, a, results)
    for i, axis, tf in summary.timefreq:
        tag = f"_{i + 1}" if len(summary.bags) > 1 else ""
        name = Path(summary.bags[i]).name
        files.append(plots.plot_spectrogram(
            out / f"spectrogram{tag}_{axis}.png",
            f"Top-stage velocity, axis {axis}, {name} (dashed: mode switches; shaded: excited)",
            tf))
        files.append(plots.plot_blrms(
            out / f"blrms{tag}_{axis}.png",
            f"Band-limited RMS of the top-stage velocity, axis {axis}, {name}", tf))
    if export is not None:
        files += write_spectra(out, results, summary.axes, export)
    summary.files = [str(p) for p in [out / "report.md", *files, out / "summary.json"]]
    (out / "report.md").write_text(markdown(summary, [Path(f).name for f in files]))
    (out / "summary.json").write_text(dumps(summary) + "\n")


def _curve(label: str, e: Any, i: int) -> dict[str, Any]:
    """Plot curve of stage ``i`` of an :class:`~dcsms_ros.analysis.frf.Estimate`."""
    t = e.tfs[i]
    cmp = e.compare()
    return {"label": label, "f": t.f, "h": t.h, "coherence": t.coherence,
            "averages": t.averages,
            "h_model": None if e.model is None else e.model[:, i],
            "flagged": cmp[e.stages[i]]["disagree_bands_hz"] if cmp else []}


def _figures(out: Path, axis: str, results: list[dict[str, Any]]) -> list[Path]:
    tf_curves, mob_curves, asd_curves, oct_curves = [], [], [], []
    centres = None
    for r in results:
        js, arr = r["json"], r["arrays"][axis]
        label = js["segment"]
        asd_curves.append({"label": label, "f": arr["f"], "asd": np.sqrt(arr["psd"])})
        ax = js["axes"][axis]
        centres = np.asarray(ax["third_octave_centres_hz"])
        oct_curves.append({"label": label, "rms": ax["third_octave_rms_mps"][r["top"]]})
        trans, mob = arr["estimates"]["transmissibility"], arr["estimates"]["mobility"]
        if trans.available:
            tf_curves.append(_curve(label, trans, len(trans.stages) - 1))
        if mob.available:
            mob_curves += [_curve(f"{label}: {s}", mob, i) for i, s in enumerate(mob.stages)]
    files = []
    if tf_curves:
        files.append(plots.plot_transmissibility(out / f"transmissibility_{axis}.png", axis,
                                                 tf_curves))
    if mob_curves:
        files.append(plots.plot_mobility(out / f"mobility_{axis}.png", axis, mob_curves))
    if asd_curves:
        files.append(plots.plot_asd(out / f"asd_{axis}.png", axis, asd_curves))
    if oct_curves and centres is not None:
        files.append(plots.plot_third_octave(out / f"third_octave_{axis}.png", axis, centres,
                                             oct_curves))
    return files


def markdown(summary: Summary, figures: list[str]) -> str:
    """The human-readable report."""
    lines = ["# DCSMS vibration analysis", "",
             f"Bags: {', '.join(f'`{b}`' for b in summary.bags)}  ",
             f"Configuration: `{summary.config_source or 'none recorded'}`  ",
             f"Reference mode: **{summary.reference}**; resonance "
             + ", ".join(f"{a}: {f:.2f} Hz" for a, f in summary.resonance_hz.items()), "",
             "## Mode table (paper Table 4)", "",
             "Top-stage velocity at the reference resonance, normalised to the reference mode.",
             "", _md_table4(summary), "", _md_resolution(summary), "",
             "Definition: " + " ".join(summary.definition.split()), "",
             "## Vibration criteria (one-third-octave RMS velocity, 1-80 Hz)", "",
             _md_vc(summary), "", "## What each segment can estimate", "",
             ("Transmissibility (H1 from the ground velocity) where the ground drives the "
              "stages, mobility (H1 from the recorded excitation force) in excited segments. "
              "A bin is usable where the random error of |H1| is at most 10 % (Bendat & "
              "Piersol: sqrt(1-coh)/(sqrt(coh)*sqrt(2*averages))); estimated: >= 50 % of the "
              "0.5-100 Hz bins usable for some stage, partial: >= 20 bins."), "",
             _md_estimates(summary), "", "## Loop model against the measurement", "",
             ("The discrete closed loop the engine runs (`core.loop_model`, from the recorded "
              "configuration), seen through the same Welch window, against every usable bin; "
              "bands where the two differ by more than 3 dB."), "",
             _md_model(summary), "",
             "## Actuator forces", "", _md_forces(summary), ""]
    if summary.paper is not None:
        lines[lines.index("## Vibration criteria (one-third-octave RMS velocity, 1-80 Hz)"):0] = [
            "## Paper comparison", "", _md_paper(summary), ""]
    if summary.timelines:
        lines += ["## Timeline", "", _md_timeline(summary), ""]
    if figures:
        lines += ["## Figures", ""] + [f"![{f}]({f})" for f in figures] + [""]
    if summary.warnings:
        lines += ["## Warnings", ""] + [f"- {w}" for w in summary.warnings] + [""]
    return "\n".join(lines)



def _fmt(x: Any, spec: str) -> str:
    return "-" if x is None or (isinstance(x, float) and not np.isfinite(x)) else format(x, spec)


def _md_table4(s: Summary) -> str:
    head = "| mode | " + " | ".join(f"{a.upper()} normalized | 95 % interval | "
                                    f"{a.upper()} attenuation (dB)" for a in s.axes)
    rows = [head + " | stability |", "|---|" + "---:|---:|---:|" * len(s.axes) + "---|"]
    for seg in s.segments:
        cells = []
        for a in s.axes:
            ax = seg["axes"][a]
            cells += [_fmt(ax.get("normalized"), ".3f"), modetable.interval(
                ax.get("normalized_ci")), _fmt(ax.get("attenuation_db"), "+.1f")]
        st = seg.get("stability", {})
        grow = ", ".join(f"{g['body']} {g['axis']} grows {g['rate_per_s']:.2g} /s"
                         for g in st.get("growing", []))
        wander = ", ".join(f"{g['body']} {g['axis']} x{g['factor']:.1f}, "
                           f"x{g['resolved_factor']:.1f} above {g['resolved_from_hz']:.2g} Hz"
                           for g in st.get("wander", []))
        cells.append(f"**unstable** ({grow})" if st.get("unstable") else
                     f"growing, model stable ({grow})" if grow else
                     f"steady (a wander slower than the record resolves: {wander})" if wander
                     else "steady" if st.get("checked", True) else "open loop")
        rows.append(f"| {seg['segment']} | " + " | ".join(cells) + " |")
    note = modetable.estimator_note(s.segments, s.axes)
    if note:
        rows += ["", note]
    return "\n".join(rows)


#: Frequency resolution (Hz) wanted at the TEM's 1.5-2.5 Hz air-mount resonances.
WANTED_RESOLUTION_HZ = 0.125


def _md_resolution(s: Summary) -> str:
    """The spectral resolution the mode table had (segment length and Welch segments)."""
    res = [seg["resolution_hz"] for seg in s.segments if seg.get("resolution_hz")]
    if not res:
        return ""
    worst = max(res)
    secs = min(seg["duration_s"] for seg in s.segments)
    line = (f"Spectral resolution {min(res):.3g}-{worst:.3g} Hz (Welch, Hann, 50 % overlap, "
            f">= 8 averages; the shortest segment {secs:.1f} s).")
    if worst > WANTED_RESOLUTION_HZ:
        line += (f" Coarser than {WANTED_RESOLUTION_HZ:g} Hz: a 1.5-2.5 Hz resonance spreads "
                 f"over few bins; 0.125 Hz needs segments of at least 37 s (`dcsms demo "
                 f"--segment 37`).")
    return line


def _md_paper(s: Summary) -> str:
    rows = s.paper or []
    intro = (f"The mode table against {CITATION} (the three-point TEM, measured); ratio = "
             f"ours / paper. {within(rows)} of {len(rows)} within +-30 %.")
    out = [intro, "",
           "| mode | axis | paper | ours | ratio |", "|---|---|---:|---:|---:|"]
    out += [f"| {r['mode']} | {r['axis']} | {r['paper']:.3f} | {_fmt(r['ours'], '.3f')} | "
            f"{_fmt(r['ratio'], '.2f')} |" for r in rows]
    return "\n".join(out)


def _md_vc(s: Summary) -> str:
    rows = ["| mode | axis | table | best criterion met | margin (dB) | worst band (Hz) |",
            "|---|---|---|---|---:|---:|"]
    for seg in s.segments:
        for a in s.axes:
            for table, v in seg["axes"][a]["vc"].items():
                rows.append(f"| {seg['segment']} | {a} | {table} | {v['best'] or 'none'} | "
                            f"{_fmt(v['margin_db'], '+.1f')} | "
                            f"{_fmt(v['worst_band_hz'], '.3g')} |")
    return "\n".join(rows)


def _md_estimates(s: Summary) -> str:
    rows = ["| segment | axis | estimate | from | status | usable bins (of band) |",
            "|---|---|---|---|---|---|"]
    for seg in s.segments:
        for a in s.axes:
            for kind, v in seg["axes"][a].get("estimates", {}).items():
                if v["status"] == "unavailable":
                    detail = v["reason"]
                else:
                    detail = ", ".join(f"{st} {n}" for st, n in v["usable_bins"].items())
                    detail += f" (of {v['band_bins']})"
                rows.append(f"| {seg['segment']} | {a} | {kind} | {v['source'] or '-'} | "
                            f"{v['status']} | {detail} |")
    return "\n".join(rows)


def _md_model(s: Summary) -> str:
    rows = [("| segment | axis | response | stage | compared bins (of band) | RMS error (dB) "
             "| max error (dB) | bands > 3 dB (Hz) |"), "|---|---|---|---|---:|---:|---:|---|"]
    for seg in s.segments:
        for a in s.axes:
            for kind, cmp in seg["axes"][a].get("model", {}).items():
                if cmp is None:
                    continue
                for st, c in cmp.items():
                    bands = ", ".join(f"{lo:.2f}-{hi:.2f}" for lo, hi in c["disagree_bands_hz"])
                    rows.append(f"| {seg['segment']} | {a} | {kind} | {st} | "
                                f"{c['compared_bins']} (of {c['band_bins']}) | "
                                f"{_fmt(c['rms_error_db'], '.2f')} | "
                                f"{_fmt(c['max_abs_error_db'], '.1f')} | {bands or 'none'} |")
    return "\n".join(rows) if len(rows) > 2 else "No model (no configuration or no mode)."


def _md_forces(s: Summary) -> str:
    rows = ["| mode | channel | RMS (N) | peak (N) | limit (N) | saturated samples |",
            "|---|---|---:|---:|---:|---:|"]
    for seg in s.segments:
        rows.extend(f"| {seg['segment']} | {c['channel']} | {_fmt(c['rms_n'], '.3g')} | "
                    f"{_fmt(c['peak_n'], '.3g')} | {_fmt(c['limit_n'], '.4g')} | "
                    f"{c['saturated_samples']} |" for c in seg.get("forces", []))
    return "\n".join(rows) if len(rows) > 2 else "No `/dcsms/actuators/applied` data."


def _md_timeline(s: Summary) -> str:
    """Per bag: the supervisor transitions, then the condensed windows (:mod:`.timeline`)."""
    out = []
    for bag, tl in s.timelines:
        lo, hi = tl.band_hz
        out += [(f"`{bag}`: mode in force and supervisor state at each window's end, ground "
                f"velocity band RMS ({lo:g}-{hi:g} Hz, the trip's band; loudest of "
                f"{', '.join(tl.axes)}; +- one standard deviation from the window's equivalent "
                f"degrees of freedom), peak applied force over the window. "
                f"{tl.window_s:g} s windows; shown: the first and last, every change, the "
                f"loudest ground."), ""]
        if tl.transitions:
            out += ["| t (s) | state | mode | reason |", "|---:|---|---|---|"]
            out += [f"| {e.t_s:.4f} | {e.state} | {e.mode} | {e.reason.replace('|', '/')} |"
                    for e in tl.transitions]
            out.append("")
        out += [("| window (s) | mode | state | changes | ground BLRMS (m/s) | peak force (N) | "
                "of limit |"), "|---|---|---|---:|---:|---:|---:|"]
        out += [f"| {r.t0_s:.2f}-{r.t1_s:.2f} | {r.mode or '-'} | {r.state or '-'} | "
                f"{r.changes} | {_fmt(r.loudest(), '.3g')} "
                f"+- {_fmt(100.0 * r.ground_rel_std(), '.0f')} % | "
                f"{_fmt(r.force_peak_n, '.4g')} | "
                f"{_fmt(100.0 * r.force_fraction, '.1f')} % |" for r in tl.condensed()]
        out.append("")
    return "\n".join(out).rstrip()


__all__ = ["markdown", "write_all"]
