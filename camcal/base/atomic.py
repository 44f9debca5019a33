"""Atomic output: build a file or a folder under a temporary name beside the target, then rename.

A reader never sees a half-written file or folder, and a failure leaves no
partial output behind (the temporary file or folder is removed, an existing
target is kept). Outputs get the permissions a plain ``open(target, "w")``
or ``mkdir`` would give (``0o666`` / ``0o777`` less the process umask), not
``mkstemp``'s private ``0o600``: outputs on a shared farm disk stay readable
by the rest of the pipeline.

:func:`atomic_dir` is what every verb that writes a folder uses (``solve``,
``stmap``, ``undistort``, ``rectify --write``, every ``--report DIR``,
``colour export --ocio``, ``rig export --to colmap``, ``demo``). When the
folder already exists, the run's files are moved into it at the end, each by
one rename (a file of the same name is replaced, the folder's other files are
kept); a failed run changes nothing in it. A process killed outright (no
``finally`` runs) leaves its ``.NAME.*.tmp`` folder beside the target.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path

from camcal.base.errors import CamcalError

__all__ = ["atomic_dir", "atomic_path", "atomic_write_text", "final_path", "output_folder"]

# Read once at import (os.umask can only be read by setting it, which is not thread-safe).
_UMASK = os.umask(0o022)
os.umask(_UMASK)


@contextlib.contextmanager
def atomic_path(target: str | os.PathLike, suffix: str | None = None) -> Iterator[Path]:
    """Yield a temporary path beside ``target``; on success rename it onto ``target``.

    Parameters
    ----------
    target : path
        The final file. Its parent directories are created.
    suffix : str, optional
        Suffix of the temporary file (defaults to the target's, so that
        writers choosing a format by extension, like ``cv2.imwrite``, work).
    """
    target = Path(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp_name = tempfile.mkstemp(
        prefix=f".{target.name}.", suffix=target.suffix if suffix is None else suffix, dir=target.parent
    )
    os.close(fd)
    tmp = Path(tmp_name)
    os.chmod(tmp, 0o666 & ~_UMASK)
    try:
        yield tmp
        os.replace(tmp, target)
    finally:
        if tmp.exists():
            tmp.unlink()


def atomic_write_text(target: str | os.PathLike, text: str) -> None:
    """Write ``text`` (UTF-8) to ``target`` atomically, flushed to disk."""
    with atomic_path(target) as tmp:
        with open(tmp, "w", encoding="utf-8") as handle:
            handle.write(text)
            handle.flush()
            os.fsync(handle.fileno())


@contextlib.contextmanager
def atomic_dir(target: str | os.PathLike, replace: Iterable[str] = ()) -> Iterator[Path]:
    """Yield a new, empty folder beside ``target``; on success it becomes ``target``, on any error it is removed.

    Parameters
    ----------
    target : path
        The final folder. Missing parent folders are created, and removed
        again (when still empty) if the run fails.
    replace : iterable of str
        Entries of an existing ``target`` that the run owns as a whole (e.g.
        ``solve``'s ``sparse``): removed before the run's own take their
        place, instead of being merged into.

    Notes
    -----
    A new ``target`` is one rename of the temporary folder. An existing
    ``target`` receives the temporary folder's entries one rename each
    (sub-folders merged, files of the same name replaced, its other files
    kept). Paths the run computed inside the temporary folder map to their
    final place with :func:`final_path`.
    """
    target = Path(target)
    if target.exists() and not target.is_dir():
        raise CamcalError(f"{target}: exists and is not a folder")
    created = _make_parents(target.parent)
    try:
        staging = Path(tempfile.mkdtemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent))
    except BaseException:
        _remove_empty(created)
        raise
    try:
        os.chmod(staging, 0o777 & ~_UMASK)
        yield staging
        if target.is_dir():
            _merge(staging, target, frozenset(replace))
        else:
            os.rename(staging, target)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        _remove_empty(created)
        raise
    shutil.rmtree(staging, ignore_errors=True)  # what a merge into an existing folder left: empty folders


@contextlib.contextmanager
def output_folder(path: str | os.PathLike | None) -> Iterator[Path | None]:
    """The folder an output folder names (``--report DIR``, ``--write DIR``), or None when it is not given.

    The verb writes into the yielded temporary folder beside ``path``; it is
    renamed to ``path`` when the verb's block ends and removed on any error
    (:func:`atomic_dir`: an existing folder keeps its
    other files, files of the same names are replaced at the end). Paths
    written inside it map to their final place with
    :func:`final_path`.
    """
    if path is None:
        yield None
        return
    with atomic_dir(path) as staging:
        yield staging




def final_path(path: str | os.PathLike, staging: Path, target: str | os.PathLike) -> Path:
    """Where ``path``, written inside :func:`atomic_dir`'s ``staging`` folder, is once the run succeeded.

    A path outside ``staging`` is returned unchanged.
    """
    path = Path(path)
    return Path(target) / path.relative_to(staging) if path.is_relative_to(staging) else path


def _make_parents(folder: Path) -> list[Path]:
    """Create ``folder`` and its missing parents; the ones created, outermost first."""
    missing = []
    while not folder.exists():
        missing.append(folder)
        if folder.parent == folder:
            break
        folder = folder.parent
    missing.reverse()
    created = []
    for path in missing:
        try:
            path.mkdir()
        except FileExistsError:
            continue
        except BaseException:
            _remove_empty(created)
            raise
        created.append(path)
    return created


def _remove_empty(created: list[Path]) -> None:
    """Remove the folders :func:`_make_parents` created, innermost first, while they are empty."""
    for path in reversed(created):
        try:
            path.rmdir()
        except OSError:
            return


def _merge(source: Path, target: Path, replace: frozenset[str] = frozenset()) -> None:
    """Move the entries of ``source`` into the existing folder ``target`` (one rename each, folders merged)."""
    for entry in sorted(source.iterdir()):
        destination = target / entry.name
        if entry.name in replace and destination.is_dir() and not destination.is_symlink():
            shutil.rmtree(destination)
        entry_is_dir = entry.is_dir() and not entry.is_symlink()
        if destination.is_dir() and not destination.is_symlink():
            if not entry_is_dir:
                raise CamcalError(f"{destination}: is a folder, cannot write a file there")
            _merge(entry, destination)
        else:
            os.replace(entry, destination)
