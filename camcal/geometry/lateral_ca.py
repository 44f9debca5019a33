"""Lateral chromatic aberration (TCA) from a board seen in colour: each corner found in the red, green and blue
channels separately, and Lensfun's ``poly3`` model fitted to where red and blue put it against green.

A lens with lateral chromatic aberration images each wavelength at a slightly
different magnification: a board corner lands at ``p_R``, ``p_G``, ``p_B``.
Lensfun's ``poly3`` TCA model (``LF_TCA_MODEL_POLY3``, lensfun.h; Lensfun
0.3.4 mod-subpix.cpp ``ModifyCoord_TCA_Poly3``; Panorama Tools' tca_correct)
maps the green image to the red (and blue) one radially about the lens
centre ``c``::

    p_R - c = (p_G - c) (v_R + c_R r + b_R r^2),   r = |p_G - c| / s

in Lensfun's normalised units ``s`` (half the shorter side of the image,
:mod:`camcal.io.lensfun`); the same for blue. Given the corners of every
channel, ``(v, c, b)`` is linear least squares per channel; the residual in
pixels says what the model and the corners' noise leave.

The corners of each channel are refined from the board's detection by the
X-junction fit of :func:`camcal.geometry.corners.refine_corners` (Placht 2014;
Duda & Frese 2018) on that channel alone; a corner any channel rejects is left
out.

References
----------
Lensfun, include/lensfun/lensfun.h (``lfTCAModel``) and libs/lensfun/mod-subpix.cpp.
Kaufmann, V., Ladstaedter, R. (2005). Elimination of color fringes in digital photographs caused by lateral
chromatic aberration. CIPA XX International Symposium (the tca_correct model).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from camcal.base.errors import CamcalError
from camcal.geometry.board import Board, Detection
from camcal.geometry.corners import grid_spacing_px, refine_corners

__all__ = ["LateralCA", "channel_corners", "fit_lateral_ca"]

#: Corners needed for the three terms per channel and a residual.
_MIN_CORNERS = 8


@dataclass(frozen=True)
class LateralCA:
    """Lensfun ``poly3`` TCA terms of red and blue against green, and their fit's residual.

    Attributes
    ----------
    red, blue : (3,) ndarray
        ``(v, c, b)`` of each channel.
    rms_px, max_px : (2,) ndarray
        The residual of the red and blue corners in pixels.
    n_corners : int
    """

    red: NDArray[np.float64]
    blue: NDArray[np.float64]
    rms_px: NDArray[np.float64]
    max_px: NDArray[np.float64]
    n_corners: int


def channel_corners(RGB: NDArray, board: Board, detection: Detection) -> tuple[NDArray[np.float64], NDArray]:
    """The detection's corners found again in each channel of the colour image: ``(N, 3, 2)`` in R, G, B order and
    which corners every channel's X-junction fit accepted ``(N,)``.

    Parameters
    ----------
    RGB : ndarray, shape (H, W, 3)
        The colour image the board was detected in (any scale, R, G, B order).
    board : Board
    detection : Detection
        The board found in the image (its grey version).
    """
    RGB = np.asarray(RGB)
    if RGB.ndim != 3 or RGB.shape[2] < 3:
        raise CamcalError(f"{detection.image}: lateral chromatic aberration needs a colour image, got shape "
                          f"{RGB.shape}")
    grid = np.rint(board.object_points[detection.ids, :2] / board.square).astype(np.int64)
    square = board.clear_fraction * grid_spacing_px(detection.corners_px, grid)
    corners, ok = [], np.ones(len(detection.ids), dtype=bool)
    for channel in range(3):
        refined = refine_corners(RGB[:, :, channel].astype(np.float64), detection.corners_px, square)
        corners.append(refined.corners_px)
        ok &= refined.ok
    return np.stack(corners, axis=1), ok


def fit_lateral_ca(corners: NDArray, centre_px: NDArray, unit_px: float) -> LateralCA:
    """Lensfun's ``poly3`` TCA terms from corners seen in each channel (see the module docstring).

    Parameters
    ----------
    corners : ndarray, shape (N, 3, 2)
        Each corner in the red, green and blue channel (pixels).
    centre_px : (2,) array_like
        The lens centre ``c`` in pixels.
    unit_px : float
        Lensfun's normalised unit ``s`` in pixels.

    Returns
    -------
    LateralCA

    Raises
    ------
    CamcalError
        Fewer than 8 corners, or corners that do not reach out from the centre (all within a tenth of the unit).
    """
    corners = np.asarray(corners, dtype=np.float64)
    if corners.ndim != 3 or corners.shape[1:] != (3, 2) or len(corners) < _MIN_CORNERS:
        raise CamcalError(f"lateral chromatic aberration needs at least {_MIN_CORNERS} corners seen in every "
                          f"channel, got {len(corners)}")
    centre = np.asarray(centre_px, dtype=np.float64)
    green = corners[:, 1] - centre
    r = np.linalg.norm(green, axis=1) / unit_px
    if r.max() < 0.1:
        raise CamcalError("lateral chromatic aberration: the board's corners are all near the lens centre; shoot "
                          "the board out to the image's corners")
    # (p_G - c) (v + c r + b r^2) = p_X - c, both coordinates stacked: linear in (v, c, b)
    design = np.concatenate([green[:, 0:1] * np.column_stack([np.ones_like(r), r, r * r]),
                             green[:, 1:2] * np.column_stack([np.ones_like(r), r, r * r])])
    fitted, rms, worst = [], [], []
    for channel in (0, 2):
        target = (corners[:, channel] - centre).T.ravel()
        terms, *_ = np.linalg.lstsq(design, target, rcond=None)
        distances = np.linalg.norm((design @ terms - target).reshape(2, -1), axis=0)
        fitted.append(terms)
        rms.append(float(np.sqrt(np.mean(distances**2))))
        worst.append(float(distances.max()))
    return LateralCA(fitted[0], fitted[1], np.array(rms), np.array(worst), len(corners))
