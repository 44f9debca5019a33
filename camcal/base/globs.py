"""Globs of input files (``left='shots/left*.jpg'``), absolute or relative, expanded the same way everywhere."""

from __future__ import annotations

import glob
import os

from camcal.base.errors import CamcalError

__all__ = ["expand_glob"]


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
