"""Thresholds of the safety check (:mod:`.check`), in a module light enough for the CLI to
read without importing the models."""

from __future__ import annotations

#: Default minimum gain margin (dB) and phase margin (deg) of every loop and disk.
MIN_GM_DB = 6.0
MIN_PM_DEG = 30.0
#: Predicted peak force = this many RMS (a Gaussian force exceeds it 0.006 % of the time).
PEAK_FACTOR = 4.0

__all__ = ["MIN_GM_DB", "MIN_PM_DEG", "PEAK_FACTOR"]
