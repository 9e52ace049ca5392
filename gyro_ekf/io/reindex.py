"""Make a bag cut short readable again: rebuild its MCAP summary and its metadata.yaml.

A recorder killed with `kill -9` leaves a .mcap file without its summary, Footer and
trailing magic, and no metadata.yaml; neither rosbags nor `gyro-ekf info` read that. As
`ros2 bag reindex` does for rosbag2, `reindex` reads the records of the file up to the last
complete one (a chunk cut in the middle is dropped with everything after it; one whose CRC
or decompression fails is left out alone when its record frame is whole, and the chunks
after it are kept; a record whose frame is broken ends the records read), writes every
message it found into a new bag with rosbags' Writer (metadata version 9, chunk CRCs on) in
a hidden folder inside the bag, and moves its files into place with `os.replace`, so a
failure leaves the bag as it was. The left-out bytes are gone from the bag afterwards: a
damaged chunk is unreadable to every reader (its CRC fails), and the command names each by
its offset and size, and the tail by its size. A .mcap
that is complete is never rewritten: when only metadata.yaml is missing, only that is
written. A file that holds no complete message (empty, or cut before its first) is refused
and nothing is written: a bag of no message would only replace the metadata.yaml that
still lists the topics.
"""

from __future__ import annotations

from collections.abc import Iterator
import heapq
import os
from pathlib import Path
import shutil
import struct
import tempfile
from typing import Any, NamedTuple

from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode
from rosbags.rosbag2.errors import WriterError
from rosbags.rosbag2.storage_mcap import get_qos

from gyro_ekf.io import mcap_chunks, messages as msgs
from gyro_ekf.io.batch_write import enable_chunk_crcs
from gyro_ekf.io.errors import BagError

__all__ = ['Damaged', 'ReindexResult', 'needs_reindex', 'reindex']

_RECORD = struct.Struct('<BQ')
_FOOTER, _CHUNK, _DATA_END = 0x02, 0x06, 0x0F
_FOOTER_TAIL = 9 + 20 + len(mcap_chunks.MAGIC)
_BAG_VERSION = 9


class ReindexResult(NamedTuple):
    """What `reindex` did.

    Attributes:
        mcap: the bag's .mcap file.
        messages: messages in the bag afterwards.
        topics: topics in the bag afterwards.
        dropped_bytes: bytes of the old file left out at its end (a partial or damaged
            tail).
        rewrote_mcap: the .mcap file was replaced.
        wrote_metadata: metadata.yaml was (re)written.
        damaged: the chunks before that tail left out, each alone (their CRC or
            decompression failed), with the chunks after them kept.
    """

    mcap: Path
    messages: int
    topics: int
    dropped_bytes: int
    rewrote_mcap: bool
    wrote_metadata: bool
    damaged: tuple[Damaged, ...] = ()


def _has_footer(mcap: Path) -> bool:
    """Whether the file ends with a Footer record and the trailing magic."""
    try:
        size = mcap.stat().st_size
        if size < len(mcap_chunks.MAGIC) + _FOOTER_TAIL:
            return False
        with open(mcap, 'rb') as stream:
            stream.seek(size - _FOOTER_TAIL)
            tail = stream.read(_FOOTER_TAIL)
    except OSError:
        return False
    return (tail.endswith(mcap_chunks.MAGIC)
            and _RECORD.unpack_from(tail, 0) == (_FOOTER, 20))


def needs_reindex(path: Path | str) -> str | None:
    """Say why a bag folder needs `gyro-ekf reindex`, or None if it does not (or cannot help).

    Only folders holding .mcap files qualify: a missing metadata.yaml or a .mcap without
    its Footer (a recorder that did not close it).
    """
    path = Path(path)
    if not path.is_dir():
        return None
    mcaps = sorted(path.glob('*.mcap'))
    if not mcaps:
        return None
    if not (path / 'metadata.yaml').exists():
        return 'the bag has no metadata.yaml'
    for mcap in mcaps:
        # An empty file holds nothing reindex could recover (it refuses it): no advice.
        if mcap.stat().st_size and not _has_footer(mcap):
            return f'{mcap.name} has no MCAP footer (was its recorder killed?)'
    return None


def _complete_end(mcap: Path, data: bytes) -> tuple[int, bool]:
    """Return where the complete top-level records end, and whether DataEnd or Footer came.

    Whether they came says the data section is whole.
    """
    if data[:len(mcap_chunks.MAGIC)] != mcap_chunks.MAGIC:
        raise BagError(f'{mcap}: not an MCAP file (bad leading magic)')
    pos = len(mcap_chunks.MAGIC)
    while pos + _RECORD.size <= len(data):
        opcode, length = _RECORD.unpack_from(data, pos)
        if opcode in (_DATA_END, _FOOTER):
            return pos, True
        following = pos + _RECORD.size + length
        if following > len(data):
            break
        pos = following
    return pos, False


class Damaged(NamedTuple):
    """A chunk left out of a reindexed bag: its file offset, its size and why."""

    offset: int
    size: int
    reason: str


def _recover(mcap: Path, data: bytes, end: int, whole: bool
             ) -> tuple[dict[str, mcap_chunks.TopicMessages],
                        dict[str, mcap_chunks.ChannelInfo], int, list[Damaged]]:
    """Read the messages of data[:end], leaving out damaged chunks.

    A chunk whose CRC or decompression fails but whose record frame is whole (its length
    leads to the next record) is left out alone, and the chunks after it are kept: a flipped
    bit costs its own chunk, not the rest of the recording. Any other damage ends the
    records read there, as a cut does.

    Returns:
        messages and channels by topic, where the records read end (file offset), and the
        chunks left out (file offsets, in file order).
    """
    damaged: list[Damaged] = []
    removed = 0  # bytes spliced out before the records still to read
    while True:
        try:
            found, channels = mcap_chunks.read_records(mcap, data, end)
            return found, channels, end + removed, damaged
        except mcap_chunks.McapError as err:
            # In a whole file damage is not a cut: refuse rather than drop data.
            at = err.offset
            if whole or at is None or not len(mcap_chunks.MAGIC) <= at < end:
                raise BagError(f'cannot reindex: {err}') from None
            opcode, length = _RECORD.unpack_from(data, at)
            following = at + _RECORD.size + length
            if (isinstance(err, mcap_chunks.CorruptMcap) and opcode == _CHUNK
                    and following <= end):
                # Read in file order, every record before it was whole: its file offset is
                # its offset here plus what was spliced out before it.
                damaged.append(Damaged(at + removed, following - at, err.reason))
                data = data[:at] + data[following:]
                end -= following - at
                removed += following - at
            else:
                end = at


def reindex(path: Path | str, drop_damaged: bool = False) -> ReindexResult:
    """Rebuild the summary of a bag's .mcap cut short and its metadata.yaml, in place.

    Args:
        path: the bag folder (holding one .mcap file).
        drop_damaged: rebuild a whole file too, leaving out its damaged chunks (whose
            messages are lost); without it, damage in a whole file is refused.

    Returns:
        What was recovered and written; nothing is written when the bag needs nothing
        (`needs_reindex` is None).

    Raises:
        BagError: not a folder with one .mcap, a file with no complete message (empty or
            cut before its first), a whole file that is damaged, a message type rosbags'
            Jazzy typestore does not know, or the new files cannot be written; in every
            case the bag is left as it was.
    """
    path = Path(path)
    if not path.is_dir():
        raise BagError(f'{path}: not a bag folder')
    mcaps = sorted(path.glob('*.mcap'))
    if len(mcaps) != 1:
        raise BagError(f'{path}: expected one .mcap file to reindex, found {len(mcaps)}')
    mcap = mcaps[0]
    # An empty file needs no reindex only in the sense that reindex cannot help: said below.
    if not drop_damaged and needs_reindex(path) is None and mcap.stat().st_size:
        return ReindexResult(mcap, 0, 0, 0, False, False)
    # A whole file rebuilt to leave its damaged chunks out is written anew, as a cut one.
    complete = _has_footer(mcap) and not drop_damaged
    try:
        data = mcap.read_bytes()
    except OSError as err:
        raise BagError(f'{mcap}: cannot read it: {err}') from None
    # An empty file, or one cut inside its magic, is a recording that never began, not a
    # foreign file: 'bad leading magic' would send the user looking for the wrong fault.
    if len(data) < len(mcap_chunks.MAGIC) and mcap_chunks.MAGIC.startswith(data):
        raise _nothing_to_recover(mcap, 'the file is empty' if not data else
                                  f'its {len(data)} bytes stop inside the MCAP magic')
    end, whole = _complete_end(mcap, data)
    found, channels, end, damaged = _recover(mcap, data, end, whole and complete)
    # A bag of no message would replace a metadata.yaml that still lists the topics.
    if not any(len(messages.log_time_ns) for messages in found.values()):
        raise _nothing_to_recover(mcap, f'no complete message in its {len(data)} bytes')
    aside = Path(tempfile.mkdtemp(prefix='.reindex.', suffix='.tmp', dir=path))
    try:
        staged = aside / mcap.stem
        count = _write(staged, found, channels)
        if not complete:
            os.replace(staged / f'{mcap.stem}.mcap', mcap)
        os.replace(staged / 'metadata.yaml', path / 'metadata.yaml')
    except OSError as err:
        raise BagError(f'{path}: cannot write the reindexed bag: {err}') from None
    finally:
        shutil.rmtree(aside, ignore_errors=True)
    return ReindexResult(mcap, count, len(found), 0 if complete or whole else len(data) - end,
                         not complete, True, tuple(damaged))


def _nothing_to_recover(mcap: Path, why: str) -> BagError:
    """Refuse to reindex a file that holds no message: the bag is left as it is."""
    return BagError(f'{mcap}: {why}: reindex has no message to recover, so it wrote nothing '
                    'and the bag is as it was')


def _write(staged: Path, found: dict[str, mcap_chunks.TopicMessages],
           channels: dict[str, mcap_chunks.ChannelInfo]) -> int:
    """Write every message found into a new bag at staged, in log-time order."""
    writer = Writer(staged, version=_BAG_VERSION, storage_plugin=StoragePlugin.MCAP)
    compressions = set().union(*(c.compressions for c in channels.values()))
    if 'zstd' in compressions:
        writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    enable_chunk_crcs(writer)
    topics = sorted(found, key=lambda t: (found[t].log_time_ns[:1].tolist() or [0], t))
    try:
        with writer:
            connections: list[Any] = []
            for topic in topics:
                channel = channels[topic]
                connections.append(writer.add_connection(
                    topic, channel.msgtype, typestore=msgs.TYPESTORE,
                    offered_qos_profiles=get_qos(channel.metadata)))
            streams = [_keyed(found[topic].log_time_ns.tolist(), order)
                       for order, topic in enumerate(topics)]
            count = 0
            for stamp, order, k in heapq.merge(*streams):
                writer.write(connections[order], stamp, found[topics[order]].payloads[k])
                count += 1
    except (WriterError, KeyError, ValueError) as err:
        raise BagError(f'{staged.parent.parent}: cannot write the reindexed bag: {err}'
                       ) from None
    return count


def _keyed(stamps: list[int], order: int) -> Iterator[tuple[int, int, int]]:
    """(stamp, topic order, index) of a topic's messages, for heapq.merge."""
    return ((stamp, order, k) for k, stamp in enumerate(stamps))
