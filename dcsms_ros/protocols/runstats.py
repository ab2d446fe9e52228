"""What a graph run did, in figures: control latency, late and stale samples, recorded messages.

The plant feeds :class:`LatencyHistogram` with the time from publishing sample k to receiving a
controller's force stamped k (the whole control path: decoupling, controller, three hops) and
reports its quantiles with its counters; at the end of a run :func:`summarize` turns the plant's
last report and the bag's message counts into one :class:`RunSummary` (``dcsms up: summary:``
line and ``summary.json``).
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any

#: Histogram range (s) and resolution: 20 bins per decade, so a quantile is read to +-6 %.
LATENCY_MIN_S = 1e-5
LATENCY_MAX_S = 10.0
BINS_PER_DECADE = 20


class LatencyHistogram:
    """Latencies (s) in log-spaced bins: constant memory and O(1) work per sample.

    Values below ``LATENCY_MIN_S`` fall in the first bin, above ``LATENCY_MAX_S`` in the last.
    """

    def __init__(self) -> None:
        decades = math.log10(LATENCY_MAX_S / LATENCY_MIN_S)
        self.bins = [0] * (int(round(decades * BINS_PER_DECADE)) + 1)
        self.count = 0

    def add(self, latency_s: float) -> None:
        """Count one latency (s)."""
        if latency_s <= LATENCY_MIN_S:
            i = 0
        else:
            i = min(int(math.log10(latency_s / LATENCY_MIN_S) * BINS_PER_DECADE),
                    len(self.bins) - 1)
        self.bins[i] += 1
        self.count += 1

    def quantile(self, q: float) -> float:
        """The ``q`` quantile (0..1) in s, the geometric centre of its bin; nan when empty."""
        if self.count == 0:
            return math.nan
        rank = q * self.count
        seen = 0
        for i, n in enumerate(self.bins):
            seen += n
            if seen >= rank and n:
                return LATENCY_MIN_S * 10.0 ** ((i + 0.5) / BINS_PER_DECADE)
        return LATENCY_MAX_S


#: Late fraction of a real-time run above which its summary warns (the issue's target for one
#: process per node).
LATE_WARN = 0.01
#: Fraction of the controllers' forces counted as zero (stale) above which a real-time summary
#: warns: the loop was open that often.
STALE_WARN = 0.01
#: Share of the machine's CPU its hypervisor took during a run (steal time) from which a
#: real-time summary's late-sample warning names it: a few per cent already cost deadlines on
#: the project's 2-core virtual machine (:mod:`dcsms_ros.cli.hoststeal`).
STEAL_NOTE = 0.02


@dataclass(frozen=True)
class RunSummary:
    """One run's figures.

    Attributes
    ----------
    samples : int
        Samples the plant published.
    late : int
        Samples that missed their deadline: in real time those computed after the next
        sample was due (a catch-up burst) and those dropped as overruns; in lockstep the
        timeouts.
    stale : int
        Samples at which a controller's force was stale and counted as zero (real time), after
        its first arrival.
    latency_p50_s, latency_p99_s : float
        Control latency quantiles, s (nan: none measured).
    recorded, samples_x_streams : int or None
        Messages of the per-sample streams in the bag, and samples x those streams (None: no
        recording). In lockstep that is what their publishers published (each answers every
        sample once; a retransmission repeats one): the bag holds all of it. In real time it
        is only a scale: a controller (keep-last 1) skips a sample under load and publishes
        nothing for it, the decoupling answers only the newest of the samples it read at one
        wake-up, a controller whose input is stale publishes zero forces of its own.
    published : int or None
        What the publishers of those streams published, as the recorder counted it from their
        sequence numbers (None: not known for every stream). ``recorded`` against it is the
        recorder's loss.
    lockstep : bool
        The run's schedule (what ``samples_x_streams`` means).
    forces : int
        Samples x controllers the plant takes a force from (0: not known), what ``stale``
        is a part of.
    overruns : int
        Of ``late``, the deadlines dropped from a backlog (real time: the plant fell more
        than a burst behind and moved its schedule on); they passed without a sample, so
        they count in the deadlines of :attr:`late_fraction` too.
    delayed : int
        Real time: samples x controllers at which the plant applied a fresh force that
        answered an older sample than the previous one (the controller skipped that sample
        under load, keep-last 1, or its answer came after the next sample): the loop ran with
        at least one sample more delay than its nominal one. Neither ``stale`` (older than
        ``control.input_timeout_s``) nor the latency quantiles (of forces that arrived) show
        it. 0 in lockstep. Kept out of :meth:`line`, whose fields are fixed; in
        :meth:`to_dict`.
    steal : float or None
        Share (0 to 1) of the machine's CPU time its hypervisor took while the graph ran
        (steal time, :mod:`dcsms_ros.cli.hoststeal`; None: not known). In :meth:`to_dict`, and
        in the late-sample warning from :data:`STEAL_NOTE` on.
    woke_late : int
        Real time: of ``late``, the deadlines that passed while the plant's loop, asleep until
        its next one, was not run and no thread of its process ran (the OS or the hypervisor,
        or another real-time thread on its core:
        :attr:`dcsms_ros.protocols.pacer.Pacer.woke_late`); the rest the
        loop missed while it was running (its own work, and any pause of its thread or its
        machine that fell within that work) or while another thread of its process held the
        GIL. In :meth:`to_dict` and the warning.
    paused : int
        Real time: of ``late``, the deadlines the plant's loop would have met but for the time
        it worked (computed, published, served) while no thread of its process ran
        (:attr:`dcsms_ros.protocols.pacer.Pacer.paused`); with ``woke_late``, what the
        machine took; the rest is an upper bound of the graph's own share. In
        :meth:`to_dict` and the warning.
    """

    samples: int
    late: int
    stale: int
    latency_p50_s: float
    latency_p99_s: float
    recorded: int | None = None
    samples_x_streams: int | None = None
    lockstep: bool = True
    published: int | None = None
    forces: int = 0
    overruns: int = 0
    delayed: int = 0
    steal: float | None = None
    woke_late: int = 0
    paused: int = 0

    @property
    def late_fraction(self) -> float:
        """Of the deadlines that passed (the samples and the dropped ones), the part that
        was missed (0 to 1)."""
        deadlines = self.samples + self.overruns
        return self.late / deadlines if deadlines else 0.0

    def line(self) -> str:
        """``samples N, late N (x %), stale forces N, control latency p50/p99 X/Y ms, ...``."""
        pct = 100.0 * self.late_fraction
        if self.recorded is None:
            rec = "not recorded"
        elif self.published is not None:
            rec = f"recorded {self.recorded} of {self.published} messages"
        elif self.lockstep:
            rec = f"recorded {self.recorded} of {self.samples_x_streams} messages"
        else:  # not what was published (see the class notes): only the scale is given
            rec = (f"recorded {self.recorded} stream messages (samples x streams = "
                   f"{self.samples_x_streams})")
        return (f"samples {self.samples}, late {self.late} ({pct:.3g} %), stale forces "
                f"{self.stale}, control latency p50/p99 {_ms(self.latency_p50_s)}/"
                f"{_ms(self.latency_p99_s)} ms, {rec}")

    @property
    def lost(self) -> int:
        """Messages the streams' publishers published that the bag lacks (0: none, or not
        known)."""
        if self.recorded is None or self.published is None:
            return 0
        return max(self.published - self.recorded, 0)

    def warning(self, composed: bool = False) -> str | None:
        """A warning when, in real time, more than :data:`LATE_WARN` of the samples missed
        their deadline (the loop that ran had more delay than the one configured, so its
        spectra are not the configuration's) or more than :data:`STALE_WARN` of the forces
        were stale (the loop was open that often), and, in any schedule, when the bag lacks
        messages that were published (what is analysed of it is not the whole run); None
        otherwise. ``composed``: the run was composed already (the hints say less)."""
        out = []
        if not self.lockstep and self.samples:
            if self.late_fraction > LATE_WARN:
                out.append(f"{100.0 * self.late_fraction:.3g} % of the samples missed their "
                           f"deadline: this machine did not keep the graph in real time, and "
                           f"the loop that ran had more delay than the configured one")
                if self.woke_late or self.paused:
                    out[-1] += (f"; {self.woke_late} of the {self.late} passed while the "
                                f"plant's loop waited to run after its wake-up time and "
                                f"nothing of its process ran, {self.paused} more were pushed "
                                f"back by such a pause while it worked")
                if self.steal is not None and self.steal >= STEAL_NOTE:
                    out[-1] += (f" (its hypervisor took {100.0 * self.steal:.3g} % of the "
                                f"machine's CPU meanwhile: steal time, a host busy with other "
                                f"work)")
            if self.forces and self.stale > STALE_WARN * self.forces:
                out.append(f"{100.0 * self.stale / self.forces:.3g} % of the controllers' "
                           f"forces came after control.input_timeout_s and counted as zero: "
                           f"the loop was open that often")
        if out:
            hint = ("--lockstep runs it at any speed" if composed else
                    "--composed runs the control path in one process, --lockstep at any speed")
            out[-1] += f" ({hint})"
        if self.lost and self.published:
            out.append(f"the bag lacks {self.lost} of the {self.published} messages published "
                       f"({100.0 * self.lost / self.published:.3g} %): the recorder did not "
                       f"keep up (--record-topics with fewer topics lightens it"
                       f"{'' if composed else '; --composed records in the process'})")
        return "; ".join(out) or None

    def to_dict(self) -> dict[str, Any]:
        """The fields, the late fraction and the messages the bag lacks."""
        return {**asdict(self), "late_fraction": self.late_fraction, "lost": self.lost}


def _ms(s: float) -> str:
    return "-" if math.isnan(s) else f"{s * 1e3:.3f}"


def summarize(plant: Mapping[str, str], counts: Mapping[str, int] | None,
              streams: list[str], published: Mapping[str, int] | None = None,
              steal: float | None = None) -> RunSummary:
    """The summary of a run from the plant's last diagnostics and the bag's counts.

    Parameters
    ----------
    plant : mapping
        The plant's diagnostic key/values (strings) of its last report.
    counts : mapping or None
        Message count per topic in the bag (None: not recorded).
    streams : list of str
        The per-sample topics (one message per sample each) that were to be recorded; one
        that ``counts`` lacks (a node's part that was never closed, a recorder that never
        matched it) counts as none recorded.
    published : mapping, optional
        Messages each topic's publisher published (the recorder's count, see
        :attr:`RunSummary.published`); used when it covers every recorded stream.
    steal : float, optional
        The machine's steal time over the run (:attr:`RunSummary.steal`).
    """
    samples = int(plant.get("sample", "0"))

    def num(key: str) -> float:
        try:
            return float(plant.get(key, "nan"))
        except ValueError:
            return math.nan

    late = sum(int(plant.get(k, "0")) for k in ("overruns", "late_steps", "lockstep_timeouts"))
    recorded = scale = sent = None
    if counts is not None:
        recorded = sum(counts.get(s, 0) for s in streams)
        scale = samples * len(streams)
        if streams and published and all(s in published for s in streams):
            sent = sum(published[s] for s in streams)
    return RunSummary(samples=samples, late=late, stale=int(plant.get("stale_samples", "0")),
                      forces=samples * int(plant.get("controllers", "0")),
                      latency_p50_s=num("latency_p50_ms") * 1e-3,
                      latency_p99_s=num("latency_p99_ms") * 1e-3,
                      recorded=recorded, samples_x_streams=scale,
                      lockstep=plant.get("schedule", "lockstep") == "lockstep",
                      published=sent, overruns=int(plant.get("overruns", "0")),
                      delayed=int(plant.get("delayed_samples", "0")), steal=steal,
                      woke_late=int(plant.get("woke_late_steps", "0")),
                      paused=int(plant.get("paused_steps", "0")))


__all__ = ["LATE_WARN", "STALE_WARN", "STEAL_NOTE", "LatencyHistogram", "RunSummary", "summarize"]
