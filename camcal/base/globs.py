"""Globs of input files (``left='shots/left*.jpg'``), absolute or relative, expanded the same way everywhere."""

from __future__ import annotations

import glob
import os

from camcal.base.errors import CamcalError

__all__ = ["expand_glob", "file_or_glob"]


def expand_glob(option: str, name: str, pattern: str, root: str | os.PathLike | None = None,
                what: str = "image") -> list[str]:
    """The files a glob matches, sorted; absolute or relative (to ``root``, else the cwd).

    Raises
    ------
    CamcalError
        ``"--images left=L/*.png: no image matches"`` when nothing matches.
    """
    full = os.path.join(os.fspath(root), os.path.expanduser(pattern)) if root else os.path.expanduser(pattern)
    files = sorted(path for path in glob.glob(full) if os.path.isfile(path))
    if not files:
        where = f" (in {root})" if root and not os.path.isabs(pattern) else ""
        raise CamcalError(f"{option} {name}={pattern}: no {what} matches{where}")
    return files


def file_or_glob(option: str, pattern: str | os.PathLike, what: str = "image or video") -> list[str]:
    """A file (or video) that exists, as given; else the files ``pattern`` matches as a glob, sorted.

    Raises
    ------
    CamcalError
        ``"--images shots/*.png: no image or video matches"`` when a glob matches nothing (``what`` names
        the kind of file),
        ``"cannot read shot.png (missing file)"`` for a file that is not there.
    """
    text = os.path.expanduser(os.fspath(pattern))
    if os.path.exists(text):  # a file named shot[1].png is that file
        return [text]
    if not glob.has_magic(text):
        raise CamcalError(f"cannot read {text} (missing file)")
    files = sorted(path for path in glob.glob(text) if os.path.isfile(path))
    if not files:
        raise CamcalError(f"{option} {text}: no {what} matches")
    return files
