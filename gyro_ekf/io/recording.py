"""A bag being recorded that stays readable when the recorder is killed (`gyro-ekf record`).

rosbags' Writer keeps the message index and metadata.yaml until close, and `kill -9` loses
both. Here the bag is written where it will stay (OUT/OUT.mcap) and checkpointed: every
`flush_s` (and whenever rosbags closes a full 1 MiB chunk) the pending chunk is closed, a
complete MCAP summary and footer are written after the last chunk, the file is flushed and
metadata.yaml is replaced atomically (rosbags writes it to a .tmp and renames). The next
chunk is then written over that summary. So after `kill -9` the bag is readable up to the
last checkpoint (at most `flush_s` of messages are lost); only a kill in the middle of a
checkpoint leaves a torn tail, which `gyro-ekf reindex BAG` cuts back to the last complete
chunk. With sqlite3, a checkpoint commits the transaction and refreshes metadata.yaml.
"""

from __future__ import annotations

from pathlib import Path
import time
from typing import Any

from gyro_ekf.io.batch_write import enable_chunk_crcs
from gyro_ekf.io.errors import BagError
from gyro_ekf.io.products import os_reason

__all__ = ['RecordingBag']


class _KeepOpen:
    """A file proxy whose close() only flushes: lets McapWriter.close write a summary."""

    def __init__(self, stream: Any):
        self._stream = stream

    def write(self, data: Any) -> int:
        return self._stream.write(data)

    def tell(self) -> int:
        return self._stream.tell()

    def close(self) -> None:
        self._stream.flush()


class _Checkpoint:
    """Stands in for the storage while Writer.close() runs, so it checkpoints instead."""

    def __init__(self, storage: Any, action: Any):
        self.path = storage.path
        self._action = action

    def close(self, version: int, metadata: str) -> None:
        self._action(version, metadata)


class RecordingBag:
    """A rosbag2 folder written in place and checkpointed (see the module docstring).

    Attributes:
        path: the bag folder.
        storage_file: the .mcap or .db3 file in it.
        count: messages written.
        checkpoints: checkpoints written (metadata.yaml refreshes).
    """

    def __init__(self, path: Path, storage: str = 'mcap', flush_s: float = 1.0):
        """Create the bag folder with an empty bag and its metadata.yaml.

        Raises:
            BagError: the folder exists, or the file system refused (named reason).
        """
        from rosbags.rosbag2 import StoragePlugin, Writer
        from rosbags.rosbag2.errors import WriterError

        self.path = Path(path)
        self.flush_s = flush_s
        plugin = StoragePlugin.MCAP if storage == 'mcap' else StoragePlugin.SQLITE3
        suffix = 'mcap' if storage == 'mcap' else 'db3'
        self.storage_file = self.path / f'{self.path.name}.{suffix}'
        try:
            self._writer = Writer(self.path, version=9, storage_plugin=plugin)
            enable_chunk_crcs(self._writer, sections=False)
        except WriterError as err:
            raise BagError(f'{self.path}: cannot record: {err}') from None
        self._connections: dict[str, Any] = {}
        self._chunks_seen = 0
        self._dirty = False
        self._last = time.monotonic()
        self.count = 0
        self.checkpoints = 0
        try:
            self._writer.open()
            self.checkpoint()
        except WriterError as err:
            raise BagError(f'{self.path}: cannot record: {err}') from None
        except OSError as err:
            raise BagError(f'{self.path}: cannot record: {os_reason(err)}') from None

    @property
    def _mcap(self) -> bool:
        return hasattr(self._writer.storage, 'chunks')

    def write(self, topic: str, msgtype: str, stamp_ns: int, data: bytes, qos: Any) -> None:
        """Write one serialized message (adding its topic on first use)."""
        try:
            connection = self._connections.get(topic)
            if connection is None:
                from gyro_ekf.io import messages

                connection = self._writer.add_connection(topic, msgtype,
                                                         typestore=messages.TYPESTORE,
                                                         offered_qos_profiles=[qos])
                self._connections[topic] = connection
            self._writer.write(connection, stamp_ns, data)
            self.count += 1
            self._dirty = True
            # rosbags closed a full chunk at the file position after the last checkpoint's
            # chunks (over its summary): write a summary after it at once.
            if self._mcap and len(self._writer.storage.chunks) != self._chunks_seen:
                self.checkpoint()
        except OSError as err:
            raise BagError(f'{self.storage_file}: cannot record: {os_reason(err)}') from None

    def tick(self) -> None:
        """Checkpoint when flush_s has passed since the last one and messages came since."""
        if self._dirty and time.monotonic() - self._last >= self.flush_s:
            try:
                self.checkpoint()
            except OSError as err:
                raise BagError(f'{self.storage_file}: cannot record: {os_reason(err)}') from None

    def checkpoint(self) -> None:
        """Make everything written so far readable on disk (see the module docstring)."""
        writer = self._writer
        storage = writer.storage
        if self._mcap:
            stream = storage.bio
            # Between checkpoints the file position is the end of the last chunk (rosbags
            # writes a chunk that fills up there too): close the pending one there.
            if storage.chunk.bio.tell():
                storage.close_chunk()
            data_end = stream.tell()

            def action(version: int, metadata: str) -> None:
                storage.bio = _KeepOpen(stream)
                try:
                    storage.close(version, metadata)  # summary, footer, magic; flushed
                finally:
                    storage.bio = stream
                stream.truncate()
        else:
            def action(version: int, metadata: str) -> None:
                storage.conn.commit()

        writer.storage = _Checkpoint(storage, action)
        try:
            writer.close()  # metadata.yaml written to a .tmp and renamed, after the data
        finally:
            writer.storage = storage
        if self._mcap:
            self._chunks_seen = len(storage.chunks)
            stream.seek(data_end)  # the next chunk goes over this summary
        self._dirty = False
        self._last = time.monotonic()
        self.checkpoints += 1

    def close(self) -> Path:
        """Write the last checkpoint and close the file; returns the bag folder."""
        try:
            if self._mcap:
                self.checkpoint()
                self._writer.storage.bio.close()
                self._writer.storage = None
            else:
                self._writer.close()
        except OSError as err:
            raise BagError(f'{self.storage_file}: cannot record: {os_reason(err)}') from None
        return self.path
