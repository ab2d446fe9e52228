"""The bag writers' rule: build a bag in ``<out>.partial/`` and move it to ``<out>`` only once it
is complete, so there is never a bag without metadata under the name the user asked for."""

from __future__ import annotations

from pathlib import Path

from dcsms_ros.errors import BagError


def claim(path: Path) -> tuple[Path, Path]:
    """Check that neither ``path`` nor its staging directory exists; return ``(staging,
    inner)``: ``<path>.partial`` and the bag directory inside it (already named as the bag).

    Raises
    ------
    BagError
        ``path`` or ``<path>.partial`` exists.
    """
    if path.exists():
        raise BagError(f"{path}: exists already, not overwriting")
    staging = path.with_name(path.name + ".partial")
    if staging.exists():
        raise BagError(f"{staging}: a previous unfinished bag is in the way; remove it")
    return staging, staging / path.name


def publish(path: Path, staging: Path, inner: Path) -> Path:
    """Move the finished bag ``inner`` to ``path`` (one rename) and remove ``staging``.

    Raises
    ------
    BagError
        ``path`` appeared meanwhile (the bag stays in ``inner``), or the move failed.
    """
    if path.exists():
        raise BagError(f"{path}: appeared while writing; bag left in {inner}")
    try:
        inner.rename(path)
        staging.rmdir()
    except OSError as exc:
        raise BagError(f"{path}: cannot move the finished bag from {inner}: {exc}") from None
    return path


__all__ = ["claim", "publish"]
