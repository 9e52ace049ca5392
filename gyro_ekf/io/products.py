"""What gyro-ekf's own products are, so `--force` replaces only those, and OS errors in words.

A command with `--force` may replace what an earlier run of itself wrote there, never a
user's own files: a folder is replaceable only when every entry in it matches the command's
product names (`first_foreign` finds the first one that does not). Staging leftovers of an
interrupted write (`.NAME.*.tmp`, `.NAME.*.staging`) count as products.
"""

from __future__ import annotations

from fnmatch import fnmatch
import os
from pathlib import Path

__all__ = ['BAG_FILES', 'STAGING_PATTERNS', 'first_foreign', 'os_reason']

BAG_FILES = ('metadata.yaml', 'metadata.yaml.tmp', '*.mcap', '*.mcap.zstd', '*.db3',
             '*.db3-journal', '*.db3-wal', '*.db3-shm')
"""Files of a rosbag2 folder as rosbags and gyro-ekf write them (sqlite's side files too)."""

STAGING_PATTERNS = ('.*.tmp', '.*.staging', '.*.old')
"""Hidden names of a staged write beside its target (see io.output_dir, bag_writer)."""


def first_foreign(folder: Path, files: tuple[str, ...],
                  folders: dict[str, tuple[str, ...]] | None = None) -> Path | None:
    """Find the first entry of folder (sorted, into product folders) that is not ours.

    Args:
        folder: an existing folder.
        files: name patterns of product files (fnmatch).
        folders: product sub-folder name pattern -> the file patterns inside it.

    Returns:
        The first foreign entry, or None when everything is a product.
    """
    folders = folders or {}
    for entry in sorted(folder.iterdir()):
        name = entry.name
        if entry.is_symlink():
            return entry
        if entry.is_dir():
            inner = next((v for k, v in folders.items() if fnmatch(name, k)), None)
            if inner is None:
                if any(fnmatch(name, p) for p in STAGING_PATTERNS):
                    continue
                return entry
            foreign = first_foreign(entry, inner)
            if foreign is not None:
                return foreign
        elif not any(fnmatch(name, p) for p in (*files, *STAGING_PATTERNS)):
            return entry
    return None


def os_reason(err: OSError) -> str:
    """Put an OS error in words, e.g. 'read-only file system' or 'no space left on device'."""
    return os.strerror(err.errno).lower() if err.errno else (str(err) or type(err).__name__)
