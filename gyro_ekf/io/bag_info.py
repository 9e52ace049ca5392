"""What `gyro-ekf info` says about a bag: topics, types, counts, start time and duration."""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

from gyro_ekf.core.validation import InputReport
from gyro_ekf.io.bag_open import metadata, open_bag
from gyro_ekf.io.errors import BagError
from gyro_ekf.io.sidecar import read_sidecar, sidecar_path

__all__ = ['BagSummary', 'TopicSummary', 'bag_summary']


class TopicSummary(NamedTuple):
    """A topic of a bag: name, type, message count and offered durability."""

    name: str
    msgtype: str
    count: int
    durability: str


class BagSummary(NamedTuple):
    """What `gyro-ekf info` prints about a bag.

    `converted` is what `convert --skip-bad` dropped from the log the bag was written from
    (the sidecar's record), or None.
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


def bag_summary(path: Path | str) -> BagSummary:
    """Topics, types, counts, start time and duration of a bag (from its metadata).

    Raises:
        BagError: missing or unreadable bag, or a sidecar that cannot be read or parsed.
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
    params = read_sidecar(path)
    meta = metadata(path)
    try:
        return BagSummary(
            path=path, storage=str(meta['storage_identifier']), version=int(meta['version']),
            start_time_ns=int(meta['starting_time']['nanoseconds_since_epoch']),
            duration_ns=int(meta['duration']['nanoseconds']),
            message_count=int(meta['message_count']), topics=summaries,
            sidecar=sidecar_path(path) if params is not None else None,
            converted=None if params is None else params.converted)
    except (KeyError, TypeError, ValueError) as err:
        raise BagError(f'{path / "metadata.yaml"}: missing or invalid entry {err}') from None
