"""``dcsms recover OUT``: make the bag ``OUT`` from what a recording that did not stop cleanly
left behind.

Two leftovers, both from a process killed before it could close (SIGKILL, the OOM killer, a
power cut; a closed terminal, SIGHUP, stops every process cleanly):

- ``OUT.partial``: a recorder's unfinished bag (``dcsms record``, a composed ``dcsms up
  --record``); its MCAP file is read up to the last whole chunk
  (:func:`~dcsms_ros.analysis.bagrecover.recover_unfinished`);
- ``OUT.parts``: the parts of a per-process ``dcsms up --record`` that were not merged because
  ``dcsms up`` itself was killed (its children still closed their parts); an unfinished part
  is recovered first, then every part is merged into ``OUT`` as ``dcsms up`` would have.

What the killed writer still held in memory (up to
:data:`~dcsms_ros.analysis.mcapwrite.CHUNK_MAX_AGE_S` of messages) is lost, and said.
"""

from __future__ import annotations

import argparse
import shutil
from pathlib import Path
from typing import Any

from dcsms_ros.cli.common import print_json
from dcsms_ros.cli.parts import parts_dir
from dcsms_ros.errors import BagError


def register(subparsers: Any) -> None:
    """Add the ``recover`` sub-command."""
    p = subparsers.add_parser(
        "recover", help="make a bag from what a killed recording left",
        description="Make the bag OUT from OUT.partial (a recorder killed before it closed "
        "its bag: its messages up to the last whole chunk) or OUT.parts (the unmerged parts "
        "of a per-process `dcsms up --record` that was killed); the leftovers are removed "
        "once OUT is closed.")
    p.add_argument("out", type=Path, metavar="OUT", help="the bag the recording was to make "
                   "(must not exist)")
    p.add_argument("--json", action="store_true", help="print what was recovered as JSON")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    """Handler: recover, print what was kept and lost, return 0."""
    # deferred: rosbags' reader, which `dcsms --help` must not import
    from dcsms_ros.analysis.bagmerge import merge_bags  # noqa: PLC0415
    from dcsms_ros.analysis.bagrecover import recover_parts, recover_unfinished  # noqa: PLC0415

    out: Path = args.out
    if out.exists():
        raise BagError(f"{out}: exists already, not overwriting")
    parts = parts_dir(out)
    recovered: dict[str, Any] = {}
    if parts.is_dir():
        for name, rec in recover_parts(parts).items():
            recovered[name] = {"messages": rec.messages, "lost_bytes": rec.lost_bytes}
        finished = sorted(d for d in parts.iterdir() if (d / "metadata.yaml").is_file())
        counts = merge_bags(finished, out)
        shutil.rmtree(parts, ignore_errors=True)
        source = f"{len(finished)} parts in {parts}"
    else:
        rec = recover_unfinished(out)
        counts = rec.counts
        recovered[out.name] = {"messages": rec.messages, "lost_bytes": rec.lost_bytes}
        source = str(out.with_name(out.name + ".partial"))
    if args.json:
        print_json({"bag": str(out), "counts": counts, "recovered": recovered})
        return 0
    print(f"dcsms recover: {out}: {sum(counts.values())} messages on {len(counts)} topics "
          f"from {source}")
    for name, r in recovered.items():
        print(f"  {name}: not closed; {r['messages']} messages kept up to its last whole "
              f"chunk, {r['lost_bytes']} bytes after it cut off")
    return 0
