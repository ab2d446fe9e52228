"""Table 4 of analysed segments: each segment's band RMS at the reference resonance normalised to
the reference segment's, with its 95 % interval (:mod:`.uncertainty`) and the ground-corrected
value (:mod:`.groundnorm`), written into the segments' JSON."""

from __future__ import annotations

from typing import Any

import numpy as np

from dcsms_ros.analysis import groundnorm, modetable, uncertainty
from dcsms_ros.analysis.summary import Summary


def table4(results: list[dict[str, Any]], ref_label: str, summary: Summary) -> None:
    """Normalise every result (``json``/``arrays`` of a segment) to the longest quiet segment
    of ``ref_label``; the resonance of each axis goes into ``summary``."""
    refs = [r for r in results if r["json"]["mode"].lower() == ref_label.lower()]
    if not refs:
        summary.warnings.append(f"no {ref_label} segment: Table 4 not normalised")
        return
    quiet = [r for r in refs if not r["json"]["excited"]]
    if quiet:
        refs = quiet  # an excitation is not the disturbance the paper's table compares
    else:
        summary.warnings.append(f"every {ref_label} segment is excited: Table 4 is normalised "
                                "to a response that includes the excitation")
    ref = max(refs, key=lambda r: r["json"]["duration_s"])
    for a in summary.axes:
        f, p = ref["arrays"][a]["f"], ref["arrays"][a]["psd"]
        f_r = modetable.resonance_frequency(f, np.sqrt(p))
        summary.resonance_hz[a] = f_r
        base = modetable.resonance_band_rms(f, p, f_r)
        dof = {id(r): modetable.resonance_band_dof(r["arrays"][a]["top"], r["json"]["fs_hz"],
                                                   f_r) for r in results}
        for r in results:
            arr = r["arrays"][a]
            val = modetable.resonance_band_rms(arr["f"], arr["psd"], f_r)
            norm, db = modetable.normalize(val, base)
            # the reference is 1 by definition; any other segment is an independent record
            ci = (norm, norm) if r is ref else uncertainty.ratio_interval(
                norm, dof[id(r)], dof[id(ref)])
            r["json"]["axes"][a].update(resonance_band_rms_mps=val, normalized=norm,
                                        normalized_ci=list(ci), band_dof=dof[id(r)],
                                        attenuation_db=db)
        _ground_corrected(results, ref, a, f_r)


def _ground_corrected(results: list[dict[str, Any]], ref: dict[str, Any], axis: str,
                      f_r: float) -> None:
    """``normalized_ground`` (:mod:`.groundnorm`) of every segment on ``axis`` that recorded
    the floor, on the reference's frequency grid; absent otherwise."""
    grid = ref["arrays"][axis]["f"]
    usable = [r for r in results if "ground" in r["arrays"][axis]["psd_bodies"]
              and r["arrays"][axis]["tfs"] and r["arrays"][axis]["f"].shape == grid.shape]
    if ref not in usable:
        return
    segs = [(r["arrays"][axis]["psd"], r["arrays"][axis]["psd_bodies"]["ground"],
             r["arrays"][axis]["tfs"][-1].h) for r in usable]
    values = groundnorm.normalized_cv(segs, grid, f_r, usable.index(ref))
    for r, v in zip(usable, values, strict=True):
        r["json"]["axes"][axis]["normalized_ground"] = v


__all__ = ["table4"]
