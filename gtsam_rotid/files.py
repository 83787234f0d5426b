"""The one place that writes files and lists image folders (docs/design.md §8: the I/O helpers, bottom layer).

Writing: every output goes through :func:`staged`, a staging file next to the target with a name of its own
(``.<name>.<random>.<ext>``, never a name the user may own, such as ``<name>.tmp``) that replaces the target by
one rename once complete. An existing target stays intact when writing fails or is interrupted, and the staging
file is removed. A directory output (a dataset, a folder of frames) goes through :func:`staged_directory` alike:
built in a hidden sibling, the old one set aside, the new one renamed in, and only then the old one deleted.
:func:`check_output` refuses, before any slow work, a target that exists (unless ``overwrite``), is a directory,
or lies in a missing directory: :class:`~gtsam_rotid.errors.OutputExistsError` /
:class:`~gtsam_rotid.errors.OutputError`, naming the path. An OS error while writing (a full disk, no
permission) becomes an :class:`OutputError` naming the path too.

Reading: :func:`image_files` lists a folder's images in natural order (``img2`` before ``img10``), hidden files
and other suffixes left out; :data:`IMAGE_SUFFIXES` and :data:`VIDEO_SUFFIXES` are the one list of each.
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import secrets
import shutil
import tempfile
import warnings
from collections.abc import Callable, Iterator
from pathlib import Path

from .errors import OutputError, OutputExistsError, RotIdError

#: Image files read as frames (lower case; compared with the lower-cased suffix).
IMAGE_SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm", ".pbm", ".webp", ".jp2")
#: Video files read as recordings.
VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv", ".webm", ".m4v", ".mpg", ".mpeg", ".wmv", ".ogv", ".mjpeg")

OVERWRITE_HINT = "pass overwrite=True (--overwrite on the command line) to replace it"


def check_output(path: str | os.PathLike, overwrite: bool = False, *, make_parent: bool = False) -> Path:
    """``path`` as a Path, if a file may be written there: it is not a directory, it does not exist (unless
    ``overwrite``), and its directory exists (or, with ``make_parent``, is not a file)."""
    path = Path(path)
    if path.is_dir():
        raise OutputError(f"{path} is a directory; give a file name")
    if (path.exists() or path.is_symlink()) and not overwrite:
        raise OutputExistsError(f"{path} exists; {OVERWRITE_HINT}")
    parent = path.parent
    if make_parent:
        if parent.exists() and not parent.is_dir():
            raise OutputError(f"cannot write {path}: {parent} is not a directory")
    elif not parent.is_dir():
        raise OutputError(f"cannot write {path}: the directory {parent} does not exist")
    return path


def check_outputs(paths, overwrite: bool = False) -> list[Path]:
    """:func:`check_output` of every path, the first that exists named (before any of them is written)."""
    return [check_output(p, overwrite) for p in paths]


@contextlib.contextmanager
def staged(path: str | os.PathLike, overwrite: bool = False, *, make_parent: bool = False) -> Iterator[Path]:
    """Context manager: a staging path (same directory and suffix as ``path``, so writers that choose the format
    by suffix still work) to write completely; on a clean exit it replaces ``path`` by one rename. On an error or
    an interrupt the staging file is removed and ``path`` is left as it was."""
    path = check_output(path, overwrite, make_parent=make_parent)
    try:
        if make_parent:
            path.parent.mkdir(parents=True, exist_ok=True)
        handle, name = tempfile.mkstemp(dir=path.parent, prefix=f".{path.name}.", suffix=path.suffix)
        os.close(handle)
        # mkstemp makes the file private (0600): give the output the mode a plain open() would (or the old file's)
        os.chmod(name, path.stat().st_mode & 0o777 if path.exists() else 0o666 & ~_umask())
    except OSError as exc:
        raise OutputError(f"cannot write {path}: {exc.strerror or exc}") from None
    staging = Path(name)
    try:
        yield staging
        if not overwrite and path.exists():      # appeared while we were writing: do not replace it
            raise OutputExistsError(f"{path} exists; {OVERWRITE_HINT}")
        os.replace(staging, path)
    except RotIdError:
        raise
    except OSError as exc:
        raise OutputError(f"cannot write {path}: {exc.strerror or exc}") from None
    finally:
        with contextlib.suppress(OSError):
            staging.unlink(missing_ok=True)


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def exchange(a: Path, b: Path) -> bool:
    """Swap two paths atomically (Linux ``renameat2(RENAME_EXCHANGE)``); False where the system cannot (another
    platform, an old kernel or file system), and nothing is changed then."""
    global _RENAMEAT2
    if _RENAMEAT2 is None:
        try:
            import ctypes
            import ctypes.util

            libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6", use_errno=True)
            function = libc.renameat2
            function.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
            _RENAMEAT2 = function
        except (OSError, AttributeError):
            _RENAMEAT2 = False
    if _RENAMEAT2 is False:
        return False
    at_fdcwd, rename_exchange = -100, 2
    return _RENAMEAT2(at_fdcwd, os.fsencode(a), at_fdcwd, os.fsencode(b), rename_exchange) == 0


#: libc's renameat2 once looked up (False: there is none)
_RENAMEAT2 = None


def sibling_name(target: Path, tag: str) -> Path:
    """A hidden name next to ``target`` that no user file has: ``.NAME.TAG-random`` (a staging or set-aside
    directory; files use :func:`staged`)."""
    return target.with_name(f".{target.name}.{tag}-{secrets.token_hex(4)}")


@contextlib.contextmanager
def staged_directory(target: str | os.PathLike, check: Callable[[], object] | None = None, *,
                     what: str = "directory") -> Iterator[Path]:
    """Context manager: a new hidden sibling directory of ``target`` (:func:`sibling_name`) to fill; on a clean
    exit it replaces ``target`` (if any) by it.

    The caller decides beforehand whether ``target`` may be replaced; ``check``, called again on a clean exit
    before anything is moved, raises if the target (which may have changed while the block ran) must not be. Then
    the staging directory is flushed and swapped with the old ``target`` in one atomic step where the system can
    (:func:`exchange`; else the old one renamed aside, the new one renamed in, the old one renamed back if that
    fails), the parent flushed, and only then the old one deleted (a warning naming where it is left
    if it cannot be). On an error or an interrupt in the block or in ``check`` the staging directory is removed
    and ``target`` is left as it was. OS errors propagate unchanged (the caller names them).
    """
    target = Path(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    while True:
        staging = sibling_name(target, "tmp")
        try:
            staging.mkdir()
            break
        except FileExistsError:
            continue
    moved_in = False
    try:
        yield staging
        _fsync_directory(staging)
        if check is not None:
            check()
        aside = None
        if os.path.lexists(target) and exchange(staging, target):  # one atomic step: never a moment without it
            aside = staging
        else:
            if os.path.lexists(target):
                aside = sibling_name(target, "old")
                os.rename(target, aside)
            try:
                os.rename(staging, target)
            except BaseException:
                if aside is not None:
                    os.rename(aside, target)
                raise
        moved_in = True
        _fsync_directory(target.parent)
        if aside is not None:
            try:
                shutil.rmtree(aside)
            except OSError as exc:
                warnings.warn(f"the new {what} is in place at {target}, but the old one could not be deleted "
                              f"from {aside}: {exc}", RuntimeWarning, stacklevel=3)
    finally:
        if not moved_in:
            shutil.rmtree(staging, ignore_errors=True)


def _fsync_directory(path: Path) -> None:
    """Flush a directory entry to disk where the platform allows it (best effort)."""
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def write_text(path: str | os.PathLike, text: str, overwrite: bool = False) -> Path:
    """Write ``text`` (UTF-8) to ``path`` through :func:`staged`; returns the path."""
    with staged(path, overwrite) as staging:
        staging.write_text(text, encoding="utf-8")
    return Path(path)


def write_json(path: str | os.PathLike, data, overwrite: bool = False, *, indent: int | None = None) -> Path:
    """Write ``data`` as JSON to ``path`` through :func:`staged`; returns the path."""
    return write_text(path, json.dumps(data, indent=indent) + "\n", overwrite)


def natural_key(path: str | os.PathLike) -> list:
    """Sort key of a file name with its numbers compared as numbers (``img2`` before ``img10``)."""
    return [int(part) if part.isdigit() else part.lower() for part in re.split(r"(\d+)", Path(path).name)]


def image_files(folder: str | os.PathLike) -> list[Path]:
    """The image files of ``folder`` (:data:`IMAGE_SUFFIXES`, not hidden) in natural name order."""
    return sorted((p for p in Path(folder).iterdir()
                   if p.is_file() and not p.name.startswith(".") and p.suffix.lower() in IMAGE_SUFFIXES),
                  key=natural_key)
