"""The models a camera-to-camera colour match uses: the Lut3D model and the model parser.

See :mod:`camcal.colour.match.routes` for the whole method; ``matrix3x3``,
``polynomial`` and ``root-polynomial`` come from :mod:`camcal.colour.fit.models`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from camcal.base.errors import CamcalError
from camcal.colour.fit.models import LinearTermsModel
from camcal.colour.fit.terms import parse_model_spec

__all__ = [
    "MATCH_MODELS",
    "LUT_SIZE",
    "LUT_SMOOTHING",
    "trilinear_weights",
    "Lut3DModel",
    "MatchModel",
    "parse_match_model",
]


MATCH_MODELS = ("matrix3x3", "polynomial", "root-polynomial", "lut3d")
LUT_SIZE = 17
LUT_SMOOTHING = 1e-3


# --------------------------------------------------------------------------
# 3D LUT model


def trilinear_weights(RGB: np.ndarray, size: int, lo: np.ndarray, hi: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Lattice node indices ``(N, 8)`` and trilinear weights ``(N, 8)`` of inputs ``(N, 3)``.

    Inputs are clamped to the box ``[lo, hi]``; nodes are numbered with the
    red index slowest: ``(i size + j) size + k``.
    """
    t = np.clip((RGB - lo) / (hi - lo), 0.0, 1.0) * (size - 1)
    base = np.minimum(np.floor(t).astype(np.int64), size - 2)
    frac = t - base
    index = np.empty((RGB.shape[0], 8), dtype=np.int64)
    weight = np.empty((RGB.shape[0], 8))
    for corner in range(8):
        d = np.array([(corner >> 2) & 1, (corner >> 1) & 1, corner & 1])
        node = base + d
        index[:, corner] = (node[:, 0] * size + node[:, 1]) * size + node[:, 2]
        weight[:, corner] = np.prod(np.where(d == 1, frac, 1.0 - frac), axis=1)
    return index, weight


@dataclass(frozen=True, eq=False)
class Lut3DModel:
    """A 3D lookup table from linear source RGB to linear target RGB.

    Attributes
    ----------
    table
        ``(size, size, size, 3)`` outputs at the nodes, indexed ``[r, g, b]``.
    domain_min, domain_max
        ``(3,)`` the input box the nodes span; inputs outside are clamped.
    smoothing
        The relative second-difference penalty it was fitted with.

    Notes
    -----
    ``f(x) = sum_c w_c(x) T[n_c]`` over the 8 nodes ``n_c`` of the cell
    holding ``x``, with trilinear weights ``w_c`` (the interpolation
    OpenColorIO's Lut3DTransform uses with ``INTERP_LINEAR``).
    """

    table: np.ndarray
    domain_min: np.ndarray
    domain_max: np.ndarray
    smoothing: float = LUT_SMOOTHING

    kind = "lut3d"

    def __post_init__(self) -> None:
        for name in ("table", "domain_min", "domain_max"):
            value = np.array(getattr(self, name), dtype=np.float64)
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        n = self.table.shape[0]
        if n < 2 or self.table.shape != (n, n, n, 3):
            raise CamcalError(f"a 3D LUT table must have shape (N, N, N, 3) with N >= 2, got {self.table.shape}")
        if self.domain_min.shape != (3,) or self.domain_max.shape != (3,) or np.any(self.domain_max <= self.domain_min):
            raise CamcalError("a 3D LUT domain needs domain_min < domain_max, three values each")

    @property
    def size(self) -> int:
        return int(self.table.shape[0])

    @property
    def label(self) -> str:
        return f"lut3d:{self.size}"

    def apply(self, RGB: Any) -> np.ndarray:
        """Map linear source RGB ``(..., 3)`` to linear target RGB ``(..., 3)``."""
        RGB = np.asarray(RGB, dtype=np.float64)
        if RGB.shape[-1:] != (3,):
            raise CamcalError(f"camera RGB must have shape (N, 3), got {RGB.shape}")
        flat = RGB.reshape(-1, 3)
        index, weight = trilinear_weights(flat, self.size, self.domain_min, self.domain_max)
        out = np.einsum("nc,nck->nk", weight, self.table.reshape(-1, 3)[index])
        return out.reshape(RGB.shape)

    def to_dict(self) -> dict:
        return {
            "kind": "lut3d",
            "size": self.size,
            "domain_min": [float(v) for v in self.domain_min],
            "domain_max": [float(v) for v in self.domain_max],
            "smoothing": float(self.smoothing),
            "table": [[float(v) for v in row] for row in self.table.reshape(-1, 3)],
        }


MatchModel = LinearTermsModel | Lut3DModel


def parse_match_model(text: str) -> tuple[str, int | None]:
    """Parse a match model name: ``matrix3x3``, ``root-polynomial[:D]``, ``polynomial[:N]``, ``lut3d[:N]``.

    Returns
    -------
    kind, order
        ``order`` is the degree, the number of Cheung terms or the LUT size
        (``None`` for ``matrix3x3``).

    Examples
    --------
    >>> parse_match_model("lut3d")
    ('lut3d', 17)
    >>> parse_match_model("root-polynomial:2")
    ('root-polynomial', 2)
    """
    text = str(text).strip()
    kind, _, order = text.partition(":")
    if kind == "lut3d":
        try:
            size = int(order) if order else LUT_SIZE
        except ValueError:
            raise CamcalError(f"malformed LUT size in {text!r}, expected an integer") from None
        if not 3 <= size <= 65:
            raise CamcalError(f"a 3D LUT size must be between 3 and 65, got {size}")
        return "lut3d", size
    if kind not in MATCH_MODELS:
        raise CamcalError(f"unknown match model {text!r}, expected one of: matrix3x3, root-polynomial:D, "
                          "polynomial:N, lut3d[:N]")
    if "white-preserving" in text or "wp" in text.split(":"):
        raise CamcalError(f"match models cannot be white preserving, got {text!r}")
    spec = parse_model_spec(text)
    return spec.kind, spec.order
