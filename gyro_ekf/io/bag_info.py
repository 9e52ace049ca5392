"""What `gyro-ekf info` says about a bag: topics, types, counts, start time and duration.

`verify_bag` reads every storage file the way `run` does (`mcap_chunks`): the CRCs it
carries, lengths and log times, so a damaged bag fails `info` as it fails `run`, naming the
file and the chunk's offset. It reads the whole data section: about 0.5 s for a one-hour
uncompressed bag (750 MB) and 1.6 s for the same bag zstd-compressed (118 MB) on the
project's 2-core machine, where the metadata alone takes 0.3 s. `check_metadata` then holds
what metadata.yaml states (the counts, start and duration `info` prints) to the messages
that read found, so `info` never prints a count or a time range the data contradicts.
`check_sidecar` then holds the params file beside the bag to the bag: one written with
another bag (its `trip.bag` fingerprint differs) is refused naming both (`io.sidecar`).
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

from gyro_ekf.core.validation import InputReport
from gyro_ekf.io import mcap_chunks
from gyro_ekf.io.bag_open import metadata, open_bag
from gyro_ekf.io.errors import BagError
from gyro_ekf.io.sidecar import (
    BagFingerprint, BagParams, check_belongs, read_sidecar, sidecar_path, stated_fingerprint)

__all__ = ['BagSummary', 'FileCheck', 'TopicSummary', 'bag_summary', 'check_metadata',
           'check_sidecar', 'verify_bag']


class TopicSummary(NamedTuple):
    """A topic of a bag: name, type, message count and offered durability."""

    name: str
    msgtype: str
    count: int
    durability: str


class BagSummary(NamedTuple):
    """What `gyro-ekf info` prints about a bag.

    `converted` is what `convert --skip-bad` dropped from the log the bag was written from
    (the sidecar's record), or None. `params` is the sidecar as read (None without one);
    its `bag` is the fingerprint it records, None when it records none.
    """

    path: Path
    storage: str
    version: int
    start_time_ns: int
    duration_ns: int
    message_count: int
    topics: list[TopicSummary]
    sidecar: Path | None
    converted: InputReport | None = None
    params: BagParams | None = None

    @property
    def fingerprint(self) -> BagFingerprint:
        """The bag's own fingerprint, as its metadata.yaml states it."""
        return stated_fingerprint(self.message_count, self.start_time_ns, self.duration_ns)


class FileCheck(NamedTuple):
    """What verify_bag found in one storage file.

    Attributes:
        name: the file, as metadata.yaml lists it.
        verified: what the file carries (chunks, CRCs), or None when it was not read.
        why_not: why it was not read ('' when it was).
    """

    name: str
    verified: mcap_chunks.Verified | None
    why_not: str = ''


def verify_bag(path: Path | str) -> list[FileCheck]:
    """Read every storage file of a bag through, checking what `run` checks of its bytes.

    MCAP files are walked whole by `mcap_chunks.verify_file` (CRCs, lengths, DataEnd and
    Footer, log times within their chunk). sqlite3 files carry no CRCs, files compressed as
    a whole (`compression_mode: file`) and MCAP features `mcap_chunks` does not handle are
    read by rosbags in `run`: those are listed as not checked, with the reason.

    Raises:
        BagError: a damaged file (naming it, the chunk's offset or the section, and the
            reason, e.g. 'CRC mismatch'), or one that cannot be read.
    """
    path = Path(path)
    meta = metadata(path)
    storage = str(meta.get('storage_identifier'))
    whole_file = meta.get('compression_mode')
    checks = []
    for name in [str(n) for n in meta.get('relative_file_paths') or []]:
        if storage != 'mcap':
            checks.append(FileCheck(name, None, f'{storage} storage carries no CRCs'))
            continue
        if whole_file or not name.endswith('.mcap'):
            checks.append(FileCheck(name, None, f'compressed as a whole file '
                                                f'({meta.get("compression_format")})'))
            continue
        try:
            checks.append(FileCheck(name, mcap_chunks.verify_file(path / name)))
        except mcap_chunks.CorruptMcap as err:
            raise BagError(str(err)) from None
        except mcap_chunks.UnsupportedMcap as err:
            checks.append(FileCheck(name, None, err.reason))
        except OSError as err:
            raise BagError(f'{path / name}: cannot read: {err.strerror or err}') from None
    return checks


def check_metadata(summary: BagSummary, checks: list[FileCheck]) -> None:
    """Refuse metadata.yaml stating other counts, start or duration than the data holds.

    `run` takes the counts as hints but refuses a message outside the stated time range
    ([start, start + duration]); `info` prints all of them, so each must be what the
    storage files hold. Only when every file was read through (`verify_bag`): a file read
    by rosbags alone (sqlite3, compressed as a whole) gives no count of its own.

    Raises:
        BagError: one line naming metadata.yaml and, for each field that disagrees, the
            field, the value stated and the value found.
    """
    verified = [check.verified for check in checks]
    if not verified or any(v is None for v in verified):
        return
    held: dict[str, int] = {}
    first = last = None
    for v in verified:
        assert v is not None
        for topic, count in v.counts.items():
            held[topic] = held.get(topic, 0) + count
        if v.log_times is not None:
            first = v.log_times[0] if first is None else min(first, v.log_times[0])
            last = v.log_times[1] if last is None else max(last, v.log_times[1])
    stated: dict[str, list[object]] = {}
    for topic in summary.topics:
        stated.setdefault(topic.name, []).append(topic.count)
    wrong = []
    total = sum(held.values())
    if summary.message_count != total:
        wrong.append(f'message_count {summary.message_count}, but the data holds {total}')
    for name in sorted(stated.keys() | held.keys()):
        count = held.get(name, 0)
        said = _stated_count(stated.get(name, []))
        if said is None and count:
            wrong.append(f"topic '{name}' is not in topics_with_message_count, but the data "
                         f'holds {count} messages of it')
        elif said is not None and said != count:
            wrong.append(f"topic '{name}': message_count {said}, but the data holds {count}")
    # A bag stating no messages has no start (rosbag2 writes the largest int64); the
    # count above already says what is wrong.
    if first is not None and last is not None and summary.message_count:
        start, duration = summary.start_time_ns, summary.duration_ns
        if start != first:
            wrong.append(f'starting_time {start} ns, but the first message is at {first} ns')
        if duration != last - first:
            wrong.append(f'duration {duration} ns, but the messages span {last - first} ns')
        # In run's words for a message it refuses (bag_open.check_stamp).
        for which, stamp in (('first', first), ('last', last)):
            if not start <= stamp <= start + duration:
                wrong.append(f'the {which} message, at {stamp} ns, lies outside the time range '
                             f'the bag states, [{start}, {start + duration + 1}) ns, which run '
                             'refuses')
    if wrong:
        raise BagError(f"{summary.path / 'metadata.yaml'}: states what the storage files do "
                       f"not hold: {'; '.join(wrong)}")


def _stated_count(counts: list[object]) -> object:
    """Return a topic's count as metadata.yaml states it: its entries' sum, None without one.

    A value that is no count (None, 'many', inf) is kept as it is, to be named.
    """
    if not counts:
        return None
    ints = [c for c in counts if isinstance(c, int) and not isinstance(c, bool)]
    if len(ints) == len(counts):
        return sum(ints)
    return counts[0] if len(counts) == 1 else ' + '.join(map(repr, counts))


def check_sidecar(summary: BagSummary) -> None:
    """Refuse a params file beside the bag that was written with another bag.

    After `check_metadata` in `info`: the bag's fingerprint is what metadata.yaml states, so
    a metadata.yaml the data contradicts is named as such first, not as a foreign sidecar.

    Raises:
        BagError: as `sidecar.check_belongs`: one line naming both files and fingerprints.
    """
    check_belongs(summary.path, summary.params, summary.fingerprint)


def bag_summary(path: Path | str, check: bool = True) -> BagSummary:
    """Topics, types, counts, start time and duration of a bag (from its metadata).

    Args:
        path: the bag folder.
        check: refuse a sidecar written with another bag (`check_sidecar`); False leaves
            it to the caller.

    Raises:
        BagError: missing or unreadable bag, or a sidecar that cannot be read or parsed,
            or (check) one written with another bag.
    """
    path = Path(path)
    reader = open_bag(path)
    try:
        summaries = []
        for connection in reader.connections:
            qos = getattr(connection.ext, 'offered_qos_profiles', [])
            durability = ','.join(sorted({q.durability.name.lower() for q in qos})) or '-'
            summaries.append(TopicSummary(connection.topic, connection.msgtype,
                                          connection.msgcount, durability))
    finally:
        reader.close()
    params = read_sidecar(path, check=False)
    meta = metadata(path)
    try:
        summary = BagSummary(
            path=path, storage=str(meta['storage_identifier']), version=int(meta['version']),
            start_time_ns=int(meta['starting_time']['nanoseconds_since_epoch']),
            duration_ns=int(meta['duration']['nanoseconds']),
            message_count=int(meta['message_count']), topics=summaries,
            sidecar=sidecar_path(path) if params is not None else None,
            converted=None if params is None else params.converted, params=params)
    except (KeyError, TypeError, ValueError) as err:
        raise BagError(f'{path / "metadata.yaml"}: missing or invalid entry {err}') from None
    if check:
        check_sidecar(summary)
    return summary
