"""The demo's check of the projection sigma against the truth (the board stage's sigma row).

The true projection error of a ray at infinity, in mrcal 2.2's board
gauge: each board view is posed with the estimated intrinsics held, the
estimated camera frame is carried into the true one by the chordal mean
over the views of ``R_true_i R_est_i^T``, and the estimated ray through a
pixel, so rotated, is projected by the true camera; its distance to the
pixel is the error. One calibration is one draw of the parameter error,
so the row bounds the RMS over the frame of ``error / sigma``: for a 2-D
Gaussian error whose worst-direction standard deviation is ``sigma``,
``|error| / sigma`` exceeds ``sqrt(-2 ln 0.0027) = 3.44`` with probability
at most 0.27 % (the chi distribution with 2 degrees of freedom), so the
row's tolerance is 3.44. A sigma inflated beyond use is not caught by one
draw; the coverage over seeded scenes is tested in
``tests/geometry/test_uncertainty.py``.

References
----------
Kogan, D. mrcal 2.x documentation: "Projection uncertainty"
(https://mrcal.secretsauce.net/uncertainty.html), 2022.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import NDArray

from camcal.geometry.board import Board, Detection
from camcal.geometry.suggest import pose_views
from camcal.geometry.uncertainty import projection_sigma
from camcal.model.camera import chordal_mean_rotation
from camcal.model.rig import Camera

__all__ = ["TOLERANCE_SIGMA", "board_gauge_error", "sigma_against_truth"]

#: ``sqrt(-2 ln 0.0027)``: a 2-D Gaussian error exceeds this many sigma with probability 0.27 %.
TOLERANCE_SIGMA = float(np.sqrt(-2.0 * np.log(0.0027)))


def board_gauge_error(estimated: Camera, truth: Camera, board: Board, detections: Sequence[Detection],
                      true_rotations: Sequence[NDArray], pixels: NDArray) -> NDArray[np.float64]:
    """True projection error (pixels) of the rays at infinity through ``pixels`` in the board gauge.

    ``true_rotations``: the true ``cam_from_board`` rotation of each detection's view (module docstring);
    each view is posed by :func:`camcal.geometry.suggest.pose_views`."""
    posed = pose_views(estimated, board.object_points, detections)
    R_gauge = chordal_mean_rotation(np.array([R_true @ R.T for R_true, (R, _) in zip(true_rotations, posed)]))
    rays = estimated.distortion.rays_from_pixels(pixels, estimated.K) @ R_gauge.T
    return np.linalg.norm(truth.distortion.project_rays(rays, truth.K) - pixels, axis=1)


def sigma_against_truth(estimated: Camera, truth: Camera, board: Board, detections: Sequence[Detection],
                        true_rotations: Sequence[NDArray], grid: tuple[int, int] = (9, 7)) -> tuple[float, float, float]:
    """RMS true error (px), RMS predicted sigma (px) and RMS of error / sigma over a grid of the frame."""
    width, height = estimated.image_size
    gx, gy = np.meshgrid(np.linspace(0, width - 1, grid[0]), np.linspace(0, height - 1, grid[1]))
    pixels = np.column_stack([gx.ravel(), gy.ravel()])
    error = board_gauge_error(estimated, truth, board, detections, true_rotations, pixels)
    sigma = projection_sigma(estimated, pixels)
    return tuple(float(np.sqrt(np.mean(v**2))) for v in (error, sigma, error / sigma))
