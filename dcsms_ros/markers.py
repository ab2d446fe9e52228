"""Generated blocks in text files: the parameter, benchmark and reliability tables in docs/."""

from __future__ import annotations

from pathlib import Path

from dcsms_ros.errors import DcsmsError


def replace_between_markers(path: Path, text: str, begin: str, end: str) -> None:
    """Replace what lies between the lines ``begin`` and ``end`` in ``path`` by ``text``.

    Raises
    ------
    DcsmsError
        The file cannot be read, or it lacks either marker (the file is left as it was).
    """
    try:
        doc = path.read_text()
    except OSError as exc:
        raise DcsmsError(f"{path}: cannot read: {exc.strerror}") from None
    head, sep1, rest = doc.partition(begin)
    _, sep2, tail = rest.partition(end)
    if not (sep1 and sep2):
        raise DcsmsError(f"{path}: markers '{begin}' ... '{end}' not found")
    path.write_text(f"{head}{begin}\n{text}\n{end}{tail}")
