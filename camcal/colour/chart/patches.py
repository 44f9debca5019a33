"""Patch sets: camera RGB beside reference XYZ (their CSV file: :mod:`camcal.io.patches`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from camcal.base.errors import CamcalError

__all__ = ["PatchSet"]


@dataclass(frozen=True, eq=False)
class PatchSet:
    """``N`` patches: names, camera RGB ``(N, 3)``, reference XYZ ``(N, 3)``."""

    names: tuple[str, ...]
    RGB: np.ndarray
    XYZ: np.ndarray

    def __post_init__(self) -> None:
        RGB = np.array(self.RGB, dtype=np.float64)
        XYZ = np.array(self.XYZ, dtype=np.float64)
        if RGB.ndim != 2 or RGB.shape[1] != 3 or XYZ.shape != RGB.shape or len(self.names) != RGB.shape[0]:
            raise CamcalError(
                f"a patch set needs N names, RGB (N, 3) and XYZ (N, 3), got {len(self.names)}, "
                f"{RGB.shape}, {XYZ.shape}"
            )
        object.__setattr__(self, "RGB", RGB)
        object.__setattr__(self, "XYZ", XYZ)
        object.__setattr__(self, "names", tuple(str(n) for n in self.names))

    def __len__(self) -> int:
        return len(self.names)

    def subset(self, keep: Any) -> PatchSet:
        keep = np.asarray(keep)
        idx = np.flatnonzero(keep) if keep.dtype == bool else keep
        return PatchSet(tuple(self.names[i] for i in idx), self.RGB[idx], self.XYZ[idx])
