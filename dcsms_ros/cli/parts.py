"""The parts of a recorded run of one process per node: where they go, which deployments record
in the node processes, and their merge into the one bag the user asked for (or, for a part its
process did not close, its recovery first: :mod:`dcsms_ros.analysis.bagrecover`)."""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

from dcsms_ros.errors import BagError

#: The recorder process's bag among a per-process run's parts (:func:`parts_dir`).
RECORDER_PART = "recorder"


def parts_dir(bag: Path) -> Path:
    """Where the processes of a recorded run of one process per node write their parts."""
    return bag.with_name(bag.name + ".parts")


def records_in_nodes(composed: bool, recorder: str | None) -> bool:
    """True if a recorded run of this deployment records each per-sample topic in the node
    process that publishes it (one process per node, the default recorder): then no
    recorder process subscribes to those topics, and none is waited for."""
    return not composed and (recorder or "composed") == "composed"


def merge_parts(parts: Path, bag: Path) -> int:
    """Merge the parts in ``parts`` into ``bag`` and remove them; 0, or 1 (with one line on
    stderr each) if a part was not closed or the merge failed (the parts are then kept).

    A part its process did not close (killed) is first recovered up to its last whole chunk
    (:func:`~dcsms_ros.analysis.bagrecover.recover_parts`): what that process still held in
    memory is lost, the rest is in the bag."""
    # deferred: rosbags' reader, which `dcsms --help` must not import
    from dcsms_ros.analysis.bagmerge import merge_bags  # noqa: PLC0415
    from dcsms_ros.analysis.bagrecover import recover_parts  # noqa: PLC0415

    status = 0
    try:
        for name, rec in recover_parts(parts).items():
            print(f"dcsms up: warning: {name}'s part of the bag was not closed; recovered "
                  f"{rec.messages} messages up to its last whole chunk (what the process still "
                  f"held is lost; {rec.lost_bytes} bytes cut off)", file=sys.stderr)
            status = 1
        merge_bags(sorted(d for d in parts.iterdir() if (d / "metadata.yaml").is_file()), bag)
    except BagError as exc:
        print(f"dcsms up: error: {exc}; the parts are kept in {parts} (`dcsms recover {bag}` "
              f"merges them)", file=sys.stderr)
        return 1
    shutil.rmtree(parts, ignore_errors=True)
    return status


__all__ = ["RECORDER_PART", "merge_parts", "parts_dir", "records_in_nodes"]
