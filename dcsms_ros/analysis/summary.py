"""The result of :func:`.report.analyze` and its ``summary.json`` text."""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from typing import Any

from dcsms_ros.analysis import modetable, timefreq
from dcsms_ros.analysis.timeline import Timeline
from dcsms_ros.jsonutil import jsonable


@dataclass
class Summary:
    """Result of :func:`.report.analyze`; :meth:`to_dict` is what ``summary.json`` holds.

    Attributes
    ----------
    segments : list of dict
        One per analysed segment (see ``summary.json``: ``mode``, ``segment`` (the mode, and
        the excitation when the segment is excited), ``axes.<a>.normalized``,
        ``axes.<a>.attenuation_db``, ``axes.<a>.normalized_ci``, ``axes.<a>.estimator``
        (:mod:`.table4`), ``axes.<a>.normalized_plain``,
        ``vc``, ``estimates`` (what the segment can estimate, with the usable bins),
        ``model`` (the loop model against every usable bin), ``forces`` ...).
    reference : str
        Label of the reference mode; ``resonance_hz`` its resonance per axis (Hz).
    files : list of str
        Written files (report.md, PNGs, summary.json) when ``out_dir`` was given.
    timelines : list of (str, Timeline)
        Per bag with supervisor transitions or mode switches: its path and
        :class:`~dcsms_ros.analysis.timeline.Timeline` (``summary.json``: ``timeline``, only
        when there is one).
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
    blrms_bands_hz: list[list[float]] = field(default_factory=list)
    #: (bag index, axis, TimeFrequency) of the top stage per bag and axis, for the figures
    timefreq: list[tuple[int, str, timefreq.TimeFrequency]] = field(default_factory=list)
    timelines: list[tuple[str, Timeline]] = field(default_factory=list)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready dict (no arrays of spectra; those go to the plots)."""
        extra = ({"timeline": [{"bag": b, **tl.to_dict()} for b, tl in self.timelines]}
                 if self.timelines else {})
        return jsonable({
            "bags": self.bags, "reference": self.reference, "axes": self.axes,
            "resonance_hz": self.resonance_hz, "config_source": self.config_source,
            "blrms_bands_hz": self.blrms_bands_hz,
            "table4_definition": " ".join(self.definition.split()),
            "segments": self.segments, "warnings": self.warnings, "files": self.files,
            "paper_comparison": self.paper, **extra,
        })

    def table(self) -> str:
        """The mode table as text (see :func:`modetable.format_table`) and the sentence naming
        its estimator; an excited segment is named with its excitation."""
        rows = [{**s, "mode": s.get("segment", s["mode"])} for s in self.segments]
        note = modetable.estimator_note(rows, self.axes)
        return modetable.format_table(rows, self.axes) + (f"\n{note}" if note else "")


def dumps(summary: Summary) -> str:
    """``summary.json`` text (strict JSON: non-finite numbers become null)."""
    return json.dumps(summary.to_dict(), indent=1, allow_nan=False)


__all__ = ["Summary", "dumps"]
