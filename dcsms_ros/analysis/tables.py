"""Spectra and time series out to MATLAB, numpy and pandas: ``npz``, ``mat`` and ``csv``.

Spectra (``dcsms analyze --export FMT``): one table set per analysed segment, named
``seg<NN>_<mode>[_excited]``, on the segment's own Welch frequency axis. Array names::

    freq_hz                       (F,)  Hz
    h1_v_p<i>_v_b_<a>             (F,)  complex H1 of stage i over ground, axis a (-)
    coh_v_p<i>_v_b_<a>            (F,)  its magnitude-squared coherence (-)
    h1_v_p<i>_f_p<s>_<a>          (F,)  complex H1 of stage i over the excitation force on
                                        stage s ((m/s)/N), excited segments only
    coh_v_p<i>_f_p<s>_<a>         (F,)  its coherence
    asd_v_b_<a>, asd_v_p<i>_<a>   (F,)  velocity ASD (m/s/sqrt(Hz))
    asd_f_p<s>_<a>                (F,)  excitation force ASD (N/sqrt(Hz)), excited segments
    third_octave_centre_hz        (B,)  exact base-10 band centres (Hz)
    third_octave_rms_v_b_<a>, third_octave_rms_v_p<i>_<a>   (B,)  band RMS velocity (m/s)

``npz`` and ``mat`` hold these arrays (complex as complex) plus the scalars ``mode``,
``segment``, ``bag``, ``t_start_s``, ``t_end_s``, ``fs_hz``, ``nperseg`` and ``averages``; ``csv``
writes three tables per segment (``_frf.csv``: ``freq_hz`` and every H1 as ``_re``/``_im`` with
its coherence; ``_asd.csv``; ``_third_octave.csv``) with the unit of every column in its header
(``freq_hz [Hz]``), and ``segments.csv`` lists the segments.

Time series (``dcsms export BAG``): every component of each chosen topic in SI units: ``npz``
with ``<name>_t_s`` (s from the bag's first stamp), ``<name>_stamp_ns``, ``<name>_log_ns`` (the
bag's receive time, ns) and ``<name>_<column>``
(``vx``… ``wz``, ``fx``… ``mz``, ``effort_<joint>``…) where ``<name>`` is the topic without
``/dcsms/`` and with ``/`` -> ``_``; ``csv`` one file per topic, plus ``mode.csv`` (the mode
timeline: each switch at the stamp of the first sample recorded after it, on the same ``t_s``
axis). Every file is written under a temporary name and renamed when complete, so a
failure leaves no half-written table.
"""

from __future__ import annotations

import csv
import os
import re
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
from scipy.io import savemat

from dcsms_ros.analysis import estimators as est
from dcsms_ros.analysis.reader import place_modes, read_topics
from dcsms_ros.analysis.series import column_unit
from dcsms_ros.errors import DcsmsError

FORMATS = ("npz", "csv", "mat")
SERIES_FORMATS = ("npz", "csv")


def signal_name(body: str) -> str:
    """``ground`` -> ``v_b``, ``stage2`` -> ``v_p2`` (the paper's names)."""
    return "v_b" if body == "ground" else f"v_p{body[5:]}"


def segment_arrays(result: dict[str, Any], axes: Sequence[str]) -> tuple[dict[str, Any],
                                                                         dict[str, str]]:
    """The named arrays of one analysed segment (module docstring) and their units.

    Parameters
    ----------
    result : dict
        One entry of the analysis's per-segment results (``json``, ``arrays``).
    axes : sequence of str
    """
    js, arrays = result["json"], result["arrays"]
    out: dict[str, Any] = {}
    units: dict[str, str] = {}
    first = arrays[axes[0]]
    out["freq_hz"], units["freq_hz"] = first["f"], "Hz"
    bands = est.third_octave_bands(1.0, 80.0)
    out["third_octave_centre_hz"], units["third_octave_centre_hz"] = bands[:, 0], "Hz"
    for a in axes:
        arr = arrays[a]
        for kind, e in arr["estimates"].items():
            if not e.available:
                continue
            src = "v_b" if kind == "transmissibility" else f"f_p{e.source[5:].split('.')[0]}"
            unit = "-" if kind == "transmissibility" else "(m/s)/N"
            for s, t in zip(e.stages, e.tfs, strict=False):
                key = f"{signal_name(s)}_{src}_{a}"
                out[f"h1_{key}"], units[f"h1_{key}"] = t.h, unit
                out[f"coh_{key}"], units[f"coh_{key}"] = t.coherence, "-"
            if kind == "mobility" and e.available and e.sxx is not None:
                out[f"asd_{src}_{a}"], units[f"asd_{src}_{a}"] = np.sqrt(e.sxx), "N/sqrt(Hz)"
        for body, p in arr["psd_bodies"].items():
            name = f"{signal_name(body)}_{a}"
            out[f"asd_{name}"], units[f"asd_{name}"] = np.sqrt(p), "m/s/sqrt(Hz)"
            out[f"third_octave_rms_{name}"] = est.band_rms(first["f"], p, bands)
            units[f"third_octave_rms_{name}"] = "m/s"
    meta = {"mode": js["mode"], "segment": js["segment"], "bag": js["bag"],
            "t_start_s": js["t_start_s"], "t_end_s": js["t_end_s"], "fs_hz": js["fs_hz"],
            "nperseg": js["nperseg"],
            "averages": est.welch_averages(js["samples"], js["nperseg"])}
    out.update(meta)
    units.update({"t_start_s": "s", "t_end_s": "s", "fs_hz": "Hz", "nperseg": "samples",
                  "averages": "-"})
    return out, units


def segment_stem(index: int, js: dict[str, Any]) -> str:
    """``seg01_passive``, ``seg02_dfbc_ffc_excited``."""
    mode = re.sub(r"[^a-z0-9]+", "_", js["mode"].lower()).strip("_") or "unknown"
    return f"seg{index:02d}_{mode}" + ("_excited" if js.get("excited") else "")


@contextmanager
def _atomic(path: Path) -> Iterator[Path]:
    """A temporary path renamed to ``path`` only when the block completes."""
    tmp = path.with_name(f".{path.name}.partial")
    try:
        yield tmp
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()


def _save_arrays(path: Path, fmt: str, arrays: dict[str, Any]) -> Path:
    with _atomic(path) as tmp:
        if fmt == "npz":
            with open(tmp, "wb") as fh:
                np.savez(fh, **arrays)
        else:
            savemat(tmp, arrays, do_compression=True, oned_as="column")
    return path


#: Rows formatted at a time (bounds the string buffers of a long time series).
CSV_ROWS = 100_000


def _write_csv(path: Path, header: Sequence[str], columns: Sequence[np.ndarray],
               fmts: Sequence[str] | None = None) -> Path:
    """One CSV table: a header row, then the columns (each formatted with its ``fmts`` entry,
    default ``%.10g``; integer columns keep every digit)."""
    fmts = list(fmts) if fmts is not None else ["%.10g"] * len(columns)
    row = ",".join(fmts)
    n = len(columns[0]) if columns else 0
    with _atomic(path) as tmp, open(tmp, "w", newline="") as fh:
        csv.writer(fh).writerow(header)
        for i in range(0, n, CSV_ROWS):
            # tolist(): Python ints and floats, so int64 stamps keep every digit
            chunk = zip(*(np.asarray(c[i:i + CSV_ROWS]).tolist() for c in columns),
                        strict=True)
            fh.write("".join(row % r + "\n" for r in chunk))
    return path


def write_spectra(out: Path, results: Sequence[dict[str, Any]], axes: Sequence[str],
                  fmt: str) -> list[Path]:
    """Write every segment's spectra into ``out`` (module docstring); returns the files."""
    if fmt not in FORMATS:
        raise DcsmsError(f"--export {fmt!r}: expected one of {', '.join(FORMATS)}")
    files: list[Path] = []
    index_rows = []
    for i, r in enumerate(results, start=1):
        arrays, units = segment_arrays(r, axes)
        stem = segment_stem(i, r["json"])
        if fmt in ("npz", "mat"):
            files.append(_save_arrays(out / f"{stem}.{fmt}", fmt, arrays))
        else:
            files += _spectra_csv(out, stem, arrays, units)
        index_rows.append([stem, arrays["mode"], arrays["segment"], arrays["bag"],
                           arrays["t_start_s"], arrays["t_end_s"], arrays["fs_hz"],
                           arrays["nperseg"], arrays["averages"]])
    path = out / "segments.csv"
    with _atomic(path) as tmp, open(tmp, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(["file", "mode", "segment", "bag", "t_start_s [s]", "t_end_s [s]",
                    "fs_hz [Hz]", "nperseg [samples]", "averages [-]"])
        w.writerows(index_rows)
    return [*files, path]


def _spectra_csv(out: Path, stem: str, arrays: dict[str, Any],
                 units: dict[str, str]) -> list[Path]:
    frf_h, frf_c = ["freq_hz [Hz]"], [arrays["freq_hz"]]
    asd_h, asd_c = ["freq_hz [Hz]"], [arrays["freq_hz"]]
    oct_h, oct_c = ["third_octave_centre_hz [Hz]"], [arrays["third_octave_centre_hz"]]
    for name, v in arrays.items():
        if name.startswith("h1_"):
            key = name[3:]
            frf_h += [f"{name}_re [{units[name]}]", f"{name}_im [{units[name]}]",
                      f"coh_{key} [-]"]
            frf_c += [np.real(v), np.imag(v), arrays[f"coh_{key}"]]
        elif name.startswith("asd_"):
            asd_h.append(f"{name} [{units[name]}]")
            asd_c.append(v)
        elif name.startswith("third_octave_rms_"):
            oct_h.append(f"{name} [{units[name]}]")
            oct_c.append(v)
    return [_write_csv(out / f"{stem}_frf.csv", frf_h, frf_c),
            _write_csv(out / f"{stem}_asd.csv", asd_h, asd_c),
            _write_csv(out / f"{stem}_third_octave.csv", oct_h, oct_c)]


def series_name(topic: str) -> str:
    """``/dcsms/velocity/stage2`` -> ``velocity_stage2``."""
    t = topic[len("/dcsms/"):] if topic.startswith("/dcsms/") else topic.lstrip("/")
    return re.sub(r"[^A-Za-z0-9]+", "_", t).strip("_")


def _column_key(column: str) -> str:
    return re.sub(r"[^A-Za-z0-9]+", "_", column).strip("_")


def write_timeseries(bag: str | Path, out: Path, names: Sequence[str] | None, fmt: str,
                     progress: Any = None, strict: bool = True) -> list[Path]:
    """Export the chosen topics of ``bag`` into ``out`` (module docstring); ``names`` as
    :func:`~.reader.read_topics` takes them (``strict``: each must match a numeric topic).

    Raises
    ------
    DcsmsError
        Unknown format; BagError for a bag or topic that cannot be read.
    """
    if fmt not in SERIES_FORMATS:
        raise DcsmsError(f"--format {fmt!r}: expected one of {', '.join(SERIES_FORMATS)}")
    series, modes = read_topics(bag, names, progress, strict)
    if not series:
        searched = f" among {' '.join(names)}" if names is not None else ""
        raise DcsmsError(f"{bag}: no TwistStamped, WrenchStamped or JointState topic to "
                         f"export{searched} (--topics names others)")
    t0 = min((int(s.stamp_ns[0]) for s in series.values() if s.stamp_ns.size), default=0)
    # a switch has only its bag time (String has no header): placed on the data's own time
    # axis through the longest topic's bag times, as the analysis does; exported as bag time,
    # a graph run's switches came out ~1.8e9 s (wall clock) against stamps from 0 (sim time)
    ref = max(series.values(), key=lambda s: s.stamp_ns.size)
    switches = [(ev.stamp_ns, ev.label) for ev in place_modes(modes, ref)]
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise DcsmsError(f"{out}: cannot create output directory: {exc.strerror}") from None
    files: list[Path] = []
    arrays: dict[str, Any] = {}
    for topic, s in series.items():
        name = series_name(topic)
        t = (s.stamp_ns - t0).astype(np.float64) * 1e-9
        cols = [_column_key(c) for c in s.columns]
        # the bag time too: the only time of a publisher that leaves its stamps zero
        log = s.log_ns if s.log_ns is not None else np.zeros_like(s.stamp_ns)
        if fmt == "npz":
            arrays[f"{name}_t_s"] = t
            arrays[f"{name}_stamp_ns"] = s.stamp_ns
            arrays[f"{name}_log_ns"] = log
            arrays.update({f"{name}_{c}": s.values[:, j] for j, c in enumerate(cols)})
            continue
        header = ["t_s [s]", "stamp_ns [ns]", "log_ns [ns]"] + [
            f"{c} [{column_unit(s.msgtype, raw)}]" for c, raw in zip(cols, s.columns,
                                                                      strict=True)]
        columns = [t, s.stamp_ns, log, *(s.values[:, j] for j in range(s.values.shape[1]))]
        files.append(_write_csv(out / f"{name}.csv", header, columns,
                                ["%.9f", "%d", "%d"] + ["%.17g"] * s.values.shape[1]))
    mode_t = np.array([(t - t0) * 1e-9 for t, _ in switches], dtype=np.float64)
    mode_label = np.array([m for _, m in switches], dtype=str)
    if fmt == "npz":
        arrays["mode_t_s"] = mode_t
        arrays["mode_label"] = mode_label
        files.append(_save_arrays(out / "timeseries.npz", "npz", arrays))
    else:
        files.append(_write_csv(out / "mode.csv", ["t_s [s]", "mode"], [mode_t, mode_label],
                                ["%.9f", "%s"]))
    return files


__all__ = ["FORMATS", "SERIES_FORMATS", "segment_arrays", "segment_stem", "series_name",
           "signal_name", "write_spectra", "write_timeseries"]
