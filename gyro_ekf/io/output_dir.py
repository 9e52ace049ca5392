"""The output folder of `gyro-ekf run`: its product names, checked, staged and swapped in whole.

Every writer builds its file (or bag folder) under a temporary name beside the target and
renames it into place (`staged_file`), so an interrupted run never leaves a half-written
product. `gyro-ekf run` builds all its products in a staging folder (`staged_output_dir`)
that replaces the output folder only when complete. `prepare_output_dir` refuses a folder
that already holds files unless asked to (`--force`), and even then one holding anything
but run's own products.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from fnmatch import fnmatch
import os
from pathlib import Path
import shutil
import tempfile

from gyro_ekf.io.errors import OutputError
from gyro_ekf.io.products import BAG_FILES, first_foreign, os_reason, STAGING_PATTERNS

ESTIMATES_CSV = 'estimates.csv'
ESTIMATES_BAG = 'estimates'
SUMMARY_JSON = 'summary.json'

RUN_PRODUCTS = (SUMMARY_JSON, ESTIMATES_CSV, 'trajectory.png', 'bias.png', 'errors.png',
                'nis.png')
"""Files `gyro-ekf run` writes into its output folder (besides the ESTIMATES_BAG folder)."""


def prepare_output_dir(path: Path | str, force: bool = False) -> Path:
    """Check that an output folder may be written: absent, empty, or (with force) ours.

    Nothing is created here: `staged_output_dir` builds the products beside the folder and
    renames them into place, so a run that fails leaves no folder behind.

    Raises:
        OutputError: the path is a file, a non-empty folder without force, or a folder that
            holds something `gyro-ekf run` does not write (named; force never deletes it).
    """
    path = Path(path)
    _check_products(path, force, 'run', RUN_PRODUCTS, {ESTIMATES_BAG: BAG_FILES},
                    'summary.json, estimates.csv, estimates/, the PNGs')
    return path


def _check_products(path: Path, force: bool, command: str, files: tuple[str, ...],
                    folders: dict[str, tuple[str, ...]], listed: str) -> None:
    """Refuse a file, a non-empty folder without force, or (force) one holding foreign files."""
    if path.is_symlink() or (path.exists() and not path.is_dir()):
        raise OutputError(f'{path}: exists and is not a folder')
    if path.is_dir() and any(not _staging(entry.name) for entry in path.iterdir()):
        if not force:
            raise OutputError(f'{path}: folder is not empty; use --force to overwrite its '
                              'products')
        foreign = first_foreign(path, files, folders)
        if foreign is not None:
            raise OutputError(f'{foreign}: is not a product of gyro-ekf {command}; --force '
                              f'replaces only its own products ({listed}): move it away first')


DEMO_PRODUCTS = (SUMMARY_JSON, 'trajectory.png', '*.log')
"""Files `gyro-ekf demo` writes into its output folder (the processes' logs among them)."""

DEMO_FOLDERS = {'bag': BAG_FILES, 'ros_log': ('*',)}
"""Folders `gyro-ekf demo` writes into its output folder: the recorded bag, the ROS logs."""


def prepare_demo_dir(path: Path | str, force: bool = False) -> Path:
    """Check and create the output folder of `gyro-ekf demo`: absent, empty, or (force) ours.

    The demo's processes write their logs and the recorded bag into the folder as they run,
    so it is created here, before any of them starts; with force, the products of an
    earlier demo are overwritten (never anything else).

    Raises:
        OutputError: the path is a file, a non-empty folder without force, a folder holding
            something `gyro-ekf demo` does not write (named), or it cannot be created.
    """
    path = Path(path)
    _check_products(path, force, 'demo', DEMO_PRODUCTS, DEMO_FOLDERS,
                    'summary.json, trajectory.png, the *.log files, bag/, ros_log/')
    try:
        path.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise OutputError(f'{path}: cannot write the outputs: {os_reason(err)}') from None
    return path


@contextmanager
def staged_output_dir(path: Path | str, force: bool = False) -> Iterator[Path]:
    """Yield a staging folder beside path; on success its products replace path's.

    A previous output stays untouched until the new one is complete (then its products go,
    including any the new run does not write, such as figures after --no-plots); the folder
    itself stays. On any failure the staging folder is removed, and so are the folders
    made for it (`-o new/out` of a run that fails leaves no `new/`). OS errors (read-only
    file system, disk full) become one OutputError naming the path.

    Raises:
        OutputError: as prepare_output_dir, or the file system refused a write.
    """
    path = prepare_output_dir(path, force)
    where = path.absolute()  # `-o .` has no name of its own to stage beside
    try:
        base = _stage_in(where)
        made = [folder for folder in (base, *base.parents) if not folder.exists()]
        base.mkdir(parents=True, exist_ok=True)
        staging = Path(tempfile.mkdtemp(prefix=f'.{where.name}.', suffix='.staging',
                                        dir=base))
    except OSError as err:
        raise OutputError(f'{path}: cannot write the outputs: {os_reason(err)}') from None
    done = False
    try:
        yield staging
        os.chmod(staging, 0o777 & ~umask())
        _swap_into_place(staging, where, force)
        done = True
    except OSError as err:
        raise OutputError(f'{path}: cannot write the outputs: {os_reason(err)}') from None
    except OutputError as err:
        # A writer inside names its staged file; the user knows only the output folder.
        raise OutputError(str(err).replace(str(staging), str(path))) from None
    finally:
        shutil.rmtree(staging, ignore_errors=True)
        for folder in made if not done else ():  # deepest first, each only if empty
            try:
                folder.rmdir()
            except OSError:
                break


def _stage_in(where: Path) -> Path:
    """Return the folder to stage in: beside `where`, or inside it when it is a mount point.

    A rename cannot cross file systems: an output folder that is a mount point of its own
    (a container's volume) got "invalid cross-device link" from a staging folder beside it.
    """
    try:
        if where.is_dir() and where.stat().st_dev != where.parent.stat().st_dev:
            return where
    except OSError:
        pass
    return where.parent


def _staging(name: str) -> bool:
    return any(fnmatch(name, pattern) for pattern in STAGING_PATTERNS)


def _swap_into_place(staging: Path, path: Path, force: bool) -> None:
    """Move the staged products into path (created if missing); old products are removed.

    An existing folder stays (its permissions, a mount point, a shell's cwd): its old
    products are moved aside first (beside the staging folder: inside a mount point, beside
    it otherwise) and restored if a move fails.
    """
    if not path.exists():
        os.replace(staging, path)
        return
    prepare_output_dir(path, force)  # again: nothing foreign appeared during the run
    old = Path(tempfile.mkdtemp(prefix=f'.{path.name}.', suffix='.old', dir=staging.parent))
    moved_old: list[str] = []
    moved_new: list[str] = []
    try:
        for entry in sorted(path.iterdir()):
            if entry in (staging, old):
                continue
            os.replace(entry, old / entry.name)
            moved_old.append(entry.name)
        for entry in sorted(staging.iterdir()):
            os.replace(entry, path / entry.name)
            moved_new.append(entry.name)
    except OSError:
        for name in moved_new:
            _remove(path / name)
        for name in moved_old:
            os.replace(old / name, path / name)
        raise
    finally:
        shutil.rmtree(old, ignore_errors=True)


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)


def umask() -> int:
    """Return the process mask of file permissions (reading it means setting it back)."""
    mask = os.umask(0)
    os.umask(mask)
    return mask


def check_output_file(path: Path, force: bool, kind: str, create_parent: bool = False) -> None:
    """Refuse a one-file output (`stress -o`, `calibrate-mounts -o`) before any work.

    Said before the work (minutes of trips, a reference run and a fit), not after it.

    Args:
        path: the file to write.
        force: an existing file may be replaced.
        kind: what the file is, for the message ('a JSON', 'a params').
        create_parent: make a missing parent folder (`make stress` writes into results/);
            else a missing one is refused.

    Raises:
        OutputError: a folder or other non-file, an existing file without force, or a
            folder in which no file can be created (missing, read-only, no permission).
    """
    if path.exists() and not path.is_file():
        raise OutputError(f'{path}: is a folder; give {kind} file name' if path.is_dir()
                          else f'{path}: is not a file; give {kind} file name')
    if path.exists() and not force:
        raise OutputError(f'{path}: exists; --force replaces a file')
    try:
        if create_parent:
            path.parent.mkdir(parents=True, exist_ok=True)
        # A file created and dropped there: permissions and a read-only mount both show.
        with tempfile.TemporaryFile(dir=path.parent):
            pass
    except FileExistsError:
        raise OutputError(f'{path}: cannot write: {path.parent} is not a folder') from None
    except OSError as err:
        raise OutputError(f'{path}: cannot write: {os_reason(err)}') from None


@contextmanager
def staged_file(target: Path) -> Iterator[Path]:
    """Yield a temporary path beside target; rename it onto target if the block succeeds.

    Raises:
        OutputError: the file system refused a write (read-only, full), naming target.
    """
    try:
        handle, name = tempfile.mkstemp(prefix=f'.{target.name}.', suffix='.tmp',
                                        dir=target.parent)
    except OSError as err:
        raise OutputError(f'{target}: cannot write: {os_reason(err)}') from None
    os.close(handle)
    staged = Path(name)
    try:
        yield staged
        os.chmod(staged, 0o666 & ~umask())
        os.replace(staged, target)
    except OSError as err:
        raise OutputError(f'{target}: cannot write: {os_reason(err)}') from None
    finally:
        if staged.exists():
            staged.unlink()
