"""Patch sets: camera RGB beside reference XYZ, with optional weights (their CSV file: :mod:`camcal.io.patches`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from camcal.base.errors import CamcalError

__all__ = ["PatchSet"]


@dataclass(frozen=True, eq=False)
class PatchSet:
    """``N`` patches: names, camera RGB ``(N, 3)``, reference XYZ ``(N, 3)``.

    ``weights`` (``(N,)``, positive, or ``None`` for equal weights) say how
    much each patch counts in a fit: a chart photo's patches are weighted by
    their signal-to-noise ratio (:func:`camcal.colour.chart.detect.snr_weights`).
    """

    names: tuple[str, ...]
    RGB: np.ndarray
    XYZ: np.ndarray
    weights: np.ndarray | None = None

    def __post_init__(self) -> None:
        RGB = np.array(self.RGB, dtype=np.float64)
        XYZ = np.array(self.XYZ, dtype=np.float64)
        if RGB.ndim != 2 or RGB.shape[1] != 3 or XYZ.shape != RGB.shape or len(self.names) != RGB.shape[0]:
            raise CamcalError(
                f"a patch set needs N names, RGB (N, 3) and XYZ (N, 3), got {len(self.names)}, "
                f"{RGB.shape}, {XYZ.shape}"
            )
        if self.weights is not None:
            weights = np.array(self.weights, dtype=np.float64)
            if weights.shape != (RGB.shape[0],) or not np.all(np.isfinite(weights)) or np.any(weights <= 0):
                raise CamcalError(f"patch weights must be {RGB.shape[0]} positive numbers, got shape {weights.shape}")
            object.__setattr__(self, "weights", weights)
        object.__setattr__(self, "RGB", RGB)
        object.__setattr__(self, "XYZ", XYZ)
        object.__setattr__(self, "names", tuple(str(n) for n in self.names))

    def __len__(self) -> int:
        return len(self.names)

    def subset(self, keep: Any) -> PatchSet:
        keep = np.asarray(keep)
        idx = np.flatnonzero(keep) if keep.dtype == bool else keep
        weights = None if self.weights is None else self.weights[idx]
        return PatchSet(tuple(self.names[i] for i in idx), self.RGB[idx], self.XYZ[idx], weights)
