"""Edit a bag message by message: the tests' way to make a bag the writer never would."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path
import shutil
from typing import Any

from rosbags.rosbag2 import Reader, StoragePlugin, Writer
import yaml

from gyro_ekf.io import messages as msgs
from gyro_ekf.io.bag_open import metadata
from gyro_ekf.io.batch_write import enable_chunk_crcs
from gyro_ekf.io.sidecar import fingerprint_of, sidecar_path

Item = list[Any]
"""[topic, msgtype, log time ns, message object or raw CDR bytes] of one message."""


def rewrite(source: Path, dest: Path, change: Callable[[list[Item]], list[Item] | None]
            ) -> Path:
    """Copy a bag message by message in file order after change(items), with its sidecar.

    The copy's sidecar records the new bag's fingerprint (as the writer would): the edit
    makes another bag, and the test is about its messages, not about a foreign sidecar.
    """
    with Reader(source) as reader:
        qos = {c.topic: (c.msgtype, c.ext.offered_qos_profiles) for c in reader.connections}
        items = [[c.topic, c.msgtype, t, msgs.deserialize(d, c.msgtype)]
                 for c, t, d in reader.messages()]
    items = change(items) or items
    writer = Writer(dest, version=9, storage_plugin=StoragePlugin.MCAP)
    enable_chunk_crcs(writer)
    with writer:
        connections = {topic: writer.add_connection(topic, msgtype, typestore=msgs.TYPESTORE,
                                                    offered_qos_profiles=profiles)
                       for topic, (msgtype, profiles) in qos.items()}
        for topic, msgtype, stamp, message in items:
            data = message if isinstance(message, bytes) else msgs.serialize(message)
            writer.write(connections[topic], stamp, data)
    shutil.copy(sidecar_path(source), sidecar_path(dest))
    refingerprint(dest)
    return dest


def refingerprint(bag: Path) -> None:
    """Record the bag's own fingerprint in its sidecar, where the sidecar records one."""
    path = sidecar_path(bag)
    document = yaml.safe_load(path.read_text(encoding='utf-8'))
    trip = document['/**']['ros__parameters'].get('trip', {})
    if isinstance(trip, dict) and 'bag' in trip:
        trip['bag'] = dict(fingerprint_of(metadata(bag), bag)._asdict())
        path.write_text(yaml.safe_dump(document, sort_keys=False), encoding='utf-8')


def of(items: list[Item], topic: str) -> list[Item]:
    """The items of one topic, in file order."""
    return [item for item in items if item[0] == topic]
