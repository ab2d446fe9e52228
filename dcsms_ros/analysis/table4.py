"""Table 4 of analysed segments: each segment's band power at the reference resonance normalised
to the reference segment's, with its 95 % interval, written into the segments' JSON.

``normalized`` is the ground-corrected value (:mod:`.groundnorm`) when every compared segment
recorded the floor on one frequency grid, else the plain band-RMS ratio; ``estimator`` says
which. The plain ratio is always kept as ``normalized_plain`` / ``normalized_plain_ci``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from dcsms_ros.analysis import groundnorm, modetable, uncertainty
from dcsms_ros.analysis.summary import Summary

GROUND_CV = modetable.GROUND_CV
BAND_RMS = modetable.BAND_RMS


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
        rms = {id(r): modetable.record_band_rms(r["arrays"][a]["top"], r["json"]["fs_hz"], f_r)
               for r in results}
        base = rms[id(ref)]
        dof = {id(r): modetable.resonance_band_dof(r["arrays"][a]["top"], r["json"]["fs_hz"],
                                                   f_r) for r in results}
        for r in results:
            val = rms[id(r)]
            norm, db = modetable.normalize(val, base)
            # the reference is 1 by definition; any other segment is an independent record
            ci = (norm, norm) if r is ref else uncertainty.ratio_interval(
                norm, dof[id(r)], dof[id(ref)])
            r["json"]["axes"][a].update(resonance_band_rms_mps=val, normalized=norm,
                                        normalized_ci=list(ci), band_dof=dof[id(r)],
                                        attenuation_db=db, normalized_plain=norm,
                                        normalized_plain_ci=list(ci), estimator=BAND_RMS)
        _ground_corrected(results, ref, a, f_r, dof, rms)


def _ground_corrected(results: list[dict[str, Any]], ref: dict[str, Any], axis: str,
                      f_r: float, dof: dict[int, float], rms: dict[int, float]) -> None:
    """Make the ground-corrected value (:mod:`.groundnorm`) ``normalized`` on ``axis`` when
    every segment recorded the floor on the reference's frequency grid; its interval divides
    each segment's degrees of freedom by its :func:`.groundnorm.variance_ratio`."""
    grid = ref["arrays"][axis]["f"]
    if not all("ground" in r["arrays"][axis] and r["arrays"][axis]["tfs"]
               and r["arrays"][axis]["f"].shape == grid.shape for r in results):
        return
    arrs = [r["arrays"][axis] for r in results]
    fs = [r["json"]["fs_hz"] for r in results]
    nper = [r["json"]["nperseg"] for r in results]
    k = results.index(ref)
    values = groundnorm.normalized_cv([(rms[id(r)] ** 2, x["psd_bodies"]["ground"],
                                        x["tfs"][-1].h) for r, x in zip(results, arrs,
                                                                        strict=True)],
                                      grid, f_r, k)
    ratios = [groundnorm.variance_ratio(grid, x["top"], x["ground"], f_r, s, n)
              for x, s, n in zip(arrs, fs, nper, strict=True)]
    for r, norm, ratio in zip(results, values, ratios, strict=True):
        db = modetable.normalize(norm, 1.0)[1]
        ci = (norm, norm) if r is ref else uncertainty.ratio_interval(
            norm, dof[id(r)] / ratio, dof[id(ref)] / ratios[k])
        r["json"]["axes"][axis].update(normalized=norm, normalized_ci=list(ci),
                                       attenuation_db=db, variance_ratio=ratio,
                                       estimator=GROUND_CV)


__all__ = ["BAND_RMS", "GROUND_CV", "table4"]
