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
kept); a failed run changes nothing in it.

Temporary names
---------------
Every temporary file or folder is ``.NAME.camcal-tmp.XXXXXXXX[SUFFIX]``
beside its target ``NAME`` (``XXXXXXXX``: ``tempfile``'s eight random
characters; a file keeps the target's suffix so writers that choose a
format by extension work). On every error the temporary is removed; only a
process killed outright (no ``finally`` runs: SIGKILL, power loss) leaves
it behind. Long jobs call :func:`remove_stale_temporaries` for the outputs
they are about to write, which removes exactly these names and nothing else.
"""

from __future__ import annotations

import contextlib
import os
import re
import shutil
import tempfile
from collections.abc import Iterable, Iterator
from pathlib import Path

from camcal.base.errors import CamcalError

__all__ = ["TEMPORARY_TAG", "atomic_dir", "atomic_path", "atomic_write_text", "final_path",
           "is_temporary_of", "output_folder", "remove_stale_temporaries", "scratch_dir"]

#: The word every temporary name carries: ``.NAME.camcal-tmp.XXXXXXXX[SUFFIX]``.
TEMPORARY_TAG = "camcal-tmp"
# .NAME.camcal-tmp. then tempfile's random part (8 characters of [a-z0-9_]), then the suffix
_TEMPORARY = re.compile(r"\.(.+)\." + re.escape(TEMPORARY_TAG) + r"\.[a-z0-9_]{8}(?:\..*)?", re.DOTALL)

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
        prefix=_prefix(target), suffix=target.suffix if suffix is None else suffix, dir=target.parent
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
        staging = Path(tempfile.mkdtemp(prefix=_prefix(target), dir=target.parent))
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
def scratch_dir(target: str | os.PathLike) -> Iterator[Path]:
    """Yield a new, empty folder beside ``target`` for the work of writing it, removed on exit whatever happens.

    It carries ``target``'s temporary name (``.NAME.camcal-tmp.XXXXXXXX``),
    so what a process killed outright left is cleared by
    :func:`remove_stale_temporaries` for ``target``, as its
    :func:`atomic_path` temporary would be.
    """
    target = Path(target)
    target.parent.mkdir(parents=True, exist_ok=True)
    scratch = Path(tempfile.mkdtemp(prefix=_prefix(target), dir=target.parent))
    try:
        yield scratch
    finally:
        shutil.rmtree(scratch, ignore_errors=True)


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


def _prefix(target: Path) -> str:
    return f".{target.name}.{TEMPORARY_TAG}."


def is_temporary_of(path: str | os.PathLike, target: str | os.PathLike) -> bool:
    """Whether ``path`` is a temporary name :func:`atomic_path` or :func:`atomic_dir` gives ``target``.

    Examples
    --------
    >>> is_temporary_of("out/.o.0032.png.camcal-tmp.0jfiou1u.png", "out/o.0032.png")
    True
    >>> is_temporary_of("out/.o.0032.png.0jfiou1u.png", "out/o.0032.png")  # not camcal's
    False
    """
    path, target = Path(path), Path(target)
    match = _TEMPORARY.fullmatch(path.name)
    return (match is not None and match.group(1) == target.name
            and os.path.normpath(path.parent) == os.path.normpath(target.parent))


def remove_stale_temporaries(targets: Iterable[str | os.PathLike]) -> tuple[Path, ...]:
    """Remove the temporary files and folders killed writers of ``targets`` left beside them.

    Only names of camcal's own pattern for one of ``targets`` are touched
    (:func:`is_temporary_of`); the targets themselves and every other file
    stay. Each folder is listed once. Call it only for outputs no other
    process is writing at the same time (a job, on start or resume, for the
    outputs it is about to write).

    Returns
    -------
    tuple of Path
        What was removed, sorted.
    """
    names_by_folder: dict[str, set[str]] = {}
    for target in targets:
        target = Path(target)
        names_by_folder.setdefault(os.path.normpath(target.parent), set()).add(target.name)
    removed = []
    for folder, names in names_by_folder.items():
        try:
            entries = list(os.scandir(folder))
        except (FileNotFoundError, NotADirectoryError):
            continue
        for entry in entries:
            match = _TEMPORARY.fullmatch(entry.name)
            if match is None or match.group(1) not in names:
                continue
            if entry.is_dir(follow_symlinks=False):
                shutil.rmtree(entry.path, ignore_errors=True)
            else:
                Path(entry.path).unlink(missing_ok=True)
            removed.append(Path(entry.path))
    return tuple(sorted(removed))


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
