"""Recover the MCAP bag a killed writer left unfinished, up to its last whole chunk (no rclpy).

A bag writer of this package builds ``OUT`` in ``OUT.partial/OUT/`` and moves it into place
only once closed (:mod:`.staging`): killed before that (SIGKILL, the OOM killer, a power cut),
it leaves an MCAP file without summary or footer and no ``metadata.yaml``, which no reader
opens. Its records are still there in file order: the schema and channel records of each topic
come before the first chunk that holds its messages (:class:`.mcapwrite.McapBagWriter` queues
them in that order), and every chunk carries its own length, compression and CRC.
:func:`recover_mcap` reads the records from the start, keeps every message of every whole
chunk (or loose message record), stops at the first record cut off by the kill (or the summary
of a file that was complete) and writes what it read into a new, closed bag. Lost: the
messages still in the writer's memory at the kill (its open chunk, and any chunk it had not
written yet) and the recorder's published counts (``custom_data``, written at close).

As ``ros2 bag reindex`` does for rosbag2; ``dcsms recover`` is the command.
"""

from __future__ import annotations

import shutil
import struct
import zlib
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import BinaryIO

from dcsms_ros.analysis.mcaprecords import MAGIC, MESSAGE_HEADER, OPCODES, U16, U32, U64
from dcsms_ros.analysis.mcapwrite import McapBagWriter
from dcsms_ros.errors import BagError

#: The opcodes this reader acts on; any other record is skipped whole.
_SCHEMA, _CHANNEL, _MESSAGE, _CHUNK, _DATA_END, _FOOTER = (
    OPCODES[k] for k in ("schema", "channel", "message", "chunk", "data_end", "footer"))


@dataclass(frozen=True)
class Recovered:
    """What :func:`recover_mcap` kept.

    Attributes
    ----------
    bag : Path
        The new, closed bag.
    counts : dict of str to int
        Messages per topic.
    lost_bytes : int
        Bytes at the end of the file that did not form a whole record (cut off by the kill).
    """

    bag: Path
    counts: dict[str, int]
    lost_bytes: int

    @property
    def messages(self) -> int:
        return sum(self.counts.values())


class _Fields:
    """Reads the MCAP fields of one record's body."""

    def __init__(self, body: bytes) -> None:
        self.body, self.at = body, 0

    def take(self, n: int) -> bytes:
        if self.at + n > len(self.body):
            raise ValueError("field beyond its record")
        out = self.body[self.at:self.at + n]
        self.at += n
        return out

    def u16(self) -> int:
        return int(U16.unpack(self.take(2))[0])

    def u32(self) -> int:
        return int(U32.unpack(self.take(4))[0])

    def u64(self) -> int:
        return int(U64.unpack(self.take(8))[0])

    def text(self) -> str:
        return self.take(self.u32()).decode()

    def string_map(self) -> dict[str, str]:
        end = self.u32() + self.at
        out = {}
        while self.at < end:
            key = self.text()
            out[key] = self.text()
        return out


class _Records:
    """The whole records of an MCAP file after its magic, in file order: ``(opcode, body)``.
    Iteration stops at the end of the data (``data_end``, ``footer``: :attr:`complete`), at a
    record cut off, or at opcode 0 (zeros a crash left in the file's last blocks);
    :attr:`end` is then the offset just past the last record handed out."""

    def __init__(self, f: BinaryIO, size: int) -> None:
        self.f, self.size = f, size
        self.end = f.tell()
        self.complete = False

    def __iter__(self) -> Iterator[tuple[int, bytes]]:
        f = self.f
        while True:
            head = f.read(9)
            if len(head) < 9 or head[0] == 0:
                return
            op, length = head[0], int(U64.unpack(head[1:])[0])
            if length > self.size - f.tell():  # cut off (or a damaged length): never read
                return
            body = f.read(length)
            if op in (_DATA_END, _FOOTER):
                self.complete = True
                return
            yield op, body
            self.end = f.tell()


def _chunk_messages(body: bytes) -> Iterator[tuple[int, int, bytes]]:
    """``(channel, log time ns, data)`` of the messages of one chunk record's body."""
    r = _Fields(body)
    r.u64(), r.u64()  # start and end time
    size, crc = r.u64(), r.u32()
    compression = r.text()
    comp = r.take(r.u64())
    if compression == "zstd":
        import zstandard  # noqa: PLC0415 - optional: only for compressed chunks

        try:
            raw = zstandard.ZstdDecompressor().decompress(comp, max_output_size=size)
        except zstandard.ZstdError as exc:
            raise ValueError(f"chunk does not decompress: {exc}") from None
    elif compression == "":
        raw = comp
    else:
        raise ValueError(f"chunk compression {compression!r} not supported")
    if len(raw) != size or (crc and zlib.crc32(raw) != crc):
        raise ValueError("chunk does not match its length or CRC")
    at = 0
    while at < len(raw):
        op, length = raw[at], int(U64.unpack_from(raw, at + 1)[0])
        if op == _MESSAGE:
            channel = int(U16.unpack_from(raw, at + 9)[0])
            log_ns = int(U64.unpack_from(raw, at + 15)[0])
            yield channel, log_ns, bytes(raw[at + MESSAGE_HEADER:at + 9 + length])
        at += 9 + length


def _mcap_file(staged: Path) -> Path | None:
    """The one ``.mcap`` file of an unfinished bag's directory; None if the directory is
    empty or missing (its writer was killed before it wrote anything)."""
    found = sorted(staged.iterdir()) if staged.is_dir() else []
    files = [p for p in found if p.suffix == ".mcap"]
    if not found:
        return None
    if len(files) != 1:
        raise BagError(f"{staged}: expected one .mcap file of an unfinished bag, found "
                       f"{', '.join(p.name for p in found)} (only MCAP bags can be recovered)")
    return files[0]


def recover_mcap(staged: Path, out: Path) -> Recovered:
    """Write the messages of the unfinished bag directory ``staged`` (its ``.mcap`` file) into
    the new bag ``out``, up to the first record that is cut off or damaged (a chunk whose
    length or CRC does not match, a message of a channel not declared before it): what
    follows is counted in :attr:`Recovered.lost_bytes`.

    Raises
    ------
    BagError
        ``staged`` holds no single MCAP file, the file does not start as MCAP, or ``out``
        cannot be written (then nothing is left at ``out``).
    """
    path = _mcap_file(staged)
    if path is None:  # nothing written: an empty bag
        McapBagWriter(out).close()
        return Recovered(out, {}, 0)
    schemas: dict[int, str] = {}
    channels: dict[int, str] = {}
    with path.open("rb") as f:
        if f.read(len(MAGIC)) != MAGIC:
            raise BagError(f"{path}: not an MCAP file")
        size = path.stat().st_size
        records = _Records(f, size)
        writer = McapBagWriter(out)
        try:
            for op, body in records:
                try:
                    messages = _messages(op, body, schemas, channels, writer)
                except (ValueError, KeyError, UnicodeDecodeError, BagError, struct.error):
                    break  # damaged: the rest of the file is lost
                for cid, t_ns, data in messages:
                    writer.write(channels[cid], t_ns, data)
            counts = writer.counts
            writer.close()
        except BaseException:
            writer.abort()
            raise
    lost = 0 if records.complete else size - records.end
    return Recovered(out, counts, lost)


def _messages(op: int, body: bytes, schemas: dict[int, str], channels: dict[int, str],
              writer: McapBagWriter) -> list[tuple[int, int, bytes]]:
    """Act on one record: a schema or a channel is remembered (a channel becomes a topic of
    ``writer``); returns the messages of a message or chunk record, checked whole before any
    is written (each of a known channel)."""
    r = _Fields(body)
    if op == _SCHEMA:
        sid = r.u16()
        schemas[sid] = r.text()
        return []
    if op == _CHANNEL:
        cid, sid, topic = r.u16(), r.u16(), r.text()
        if cid not in channels:
            r.text()  # message encoding: cdr
            writer.add_topic(topic, schemas[sid], r.string_map().get("offered_qos_profiles", ""))
            channels[cid] = topic
        return []
    if op == _MESSAGE:
        cid = r.u16()
        r.u32()
        out = [(cid, r.u64(), body[22:])]
    elif op == _CHUNK:
        out = list(_chunk_messages(body))
    else:
        return []
    if any(cid not in channels for cid, _, _ in out):
        raise ValueError("a message of a channel not declared before it")
    return out


def recover_unfinished(out: Path) -> Recovered:
    """Recover the bag ``out`` from its unfinished staging directory ``out.partial`` (or
    ``out.recovering``, where an interrupted recovery left it), which is removed once ``out``
    is closed.

    Raises
    ------
    BagError
        ``out`` exists, there is no unfinished bag of that name, or :func:`recover_mcap`
        failed (the unfinished bag is then kept, as ``out.recovering``).
    """
    partial = out.with_name(out.name + ".partial")
    aside = out.with_name(out.name + ".recovering")
    if out.exists():
        raise BagError(f"{out}: exists already, not overwriting")
    if partial.exists():
        if aside.exists():
            raise BagError(f"{aside}: an earlier recovery's input is in the way; remove it")
        partial.rename(aside)  # the new bag is staged in out.partial, as every bag is
    elif not aside.exists():
        raise BagError(f"{out}: no unfinished bag to recover (no {partial.name})")
    rec = recover_mcap(aside / out.name, out)
    shutil.rmtree(aside, ignore_errors=True)
    return rec


def unfinished_parts(parts: Path) -> list[str]:
    """The names of the unfinished bags in directory ``parts`` (``<name>.partial`` or
    ``<name>.recovering``), sorted."""
    return sorted({d.name.rsplit(".", 1)[0] for d in parts.iterdir()
                   if d.suffix in (".partial", ".recovering") and d.is_dir()})


def recover_parts(parts: Path) -> dict[str, Recovered]:
    """Recover every unfinished bag in ``parts`` in place (:func:`recover_unfinished`), by
    name."""
    return {name: recover_unfinished(parts / name) for name in unfinished_parts(parts)}


__all__ = ["Recovered", "recover_mcap", "recover_parts", "recover_unfinished",
           "unfinished_parts"]
