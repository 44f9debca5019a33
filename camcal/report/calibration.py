"""The ``calibrate board --report`` plots (residuals, corner coverage, RMS per image) and ``--suggest``'s preview."""

from __future__ import annotations

import colorsys
import os
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from camcal.geometry.board import Board
from camcal.geometry.zhang import CalibrationResult
from camcal.io.frames import imwrite
from camcal.model.rig import Camera
from camcal.report import RESIDUAL_LABEL
from camcal.report.volume import write_volume_report

__all__ = ["write_report", "write_suggestion_preview"]


def _palette(n: int) -> list[tuple[int, int, int]]:
    """``n`` distinct BGR colours (hues spread evenly)."""
    return [tuple(int(255 * v) for v in colorsys.hsv_to_rgb(i / max(n, 1), 0.85, 0.8)[::-1]) for i in range(n)]


def write_report(result: CalibrationResult, out_dir: str | os.PathLike, board: Board | None = None,
                 sigma_maps: Sequence[Path] = ()) -> list[Path]:
    """PNG plots of a calibration and its page, written atomically into ``out_dir``.

    Per camera, ``residuals_<camera>.png`` (every corner with its
    reprojection residual ``observed - projected`` magnified, an arrow from
    the magnified projection to the detected corner, over the image frame) and
    ``coverage_<camera>.png`` (the corners of each image in its own colour,
    with the board outline); for the whole rig, ``per_image_rms.png``
    (RMS of each image kept, one bar per image, cameras in turn, the
    median as a line); the page ``index.html`` with the camera layout and
    each camera's held-out residuals (:func:`camcal.report.volume.write_volume_report`;
    ``board`` draws the board positions as outlines; ``sigma_maps``, heat-map PNGs
    already in ``out_dir``, are shown on it).

    Returns
    -------
    list of Path
        The files written.
    """
    directory = Path(out_dir)
    written = []
    norms = np.linalg.norm(result.residuals_px, axis=1)
    for j, camera in enumerate(result.rig.cameras):
        width, height = camera.image_size
        mine = result.camera_of_point == j
        points, residuals = result.points_px[mine], -result.residuals_px[mine]  # result's are projected - detected
        gain = 0.03 * np.hypot(width, height) / max(np.percentile(norms[mine], 99), 1e-9)
        canvas = np.full((height, width, 3), 255, np.uint8)
        for p, r in zip(points, residuals):  # r = observed - projected: the projection is at p - r
            observed = tuple(int(v) for v in np.round(p))
            projected = tuple(int(v) for v in np.round(p - gain * r))
            cv2.arrowedLine(canvas, projected, observed, (40, 40, 200), 1, cv2.LINE_AA, tipLength=0.2)
            cv2.circle(canvas, observed, 1, (0, 0, 0), -1)
        cv2.putText(canvas, f"{camera.name}: {RESIDUAL_LABEL} x{gain:.0f}, RMS {camera.quality['rms_px']:.3f} px",
                    (10, 25), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 1, cv2.LINE_AA)
        written.append(imwrite(directory / f"residuals_{camera.name}.png", canvas))

        canvas = np.full((height, width, 3), 255, np.uint8)
        images = np.unique(result.image_of_point[mine])
        for image, colour in zip(images, _palette(len(images))):
            corners = result.points_px[result.image_of_point == image]
            hull = cv2.convexHull(corners.astype(np.float32)).astype(np.int32)
            cv2.polylines(canvas, [hull], True, colour, 1, cv2.LINE_AA)
            for p in corners:
                cv2.circle(canvas, tuple(int(v) for v in np.round(p)), 2, colour, -1)
        cv2.putText(canvas, f"{camera.name}: corner coverage, {len(images)} images",
                    (10, 25), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (0, 0, 0), 1, cv2.LINE_AA)
        written.append(imwrite(directory / f"coverage_{camera.name}.png", canvas))

    rms = list(result.per_image_rms_px.items())
    bar, margin, plot_height = 14, 40, 300
    canvas = np.full((plot_height + 2 * margin, 2 * margin + bar * len(rms), 3), 255, np.uint8)
    top = max(value for _, value in rms)
    colours = _palette(len(result.rig.cameras))
    index_of = {camera.name: j for j, camera in enumerate(result.rig.cameras)}
    for n, ((camera, _), value) in enumerate(rms):
        x = margin + n * bar
        y = margin + plot_height - int(plot_height * value / top)
        cv2.rectangle(canvas, (x + 1, y), (x + bar - 2, margin + plot_height), colours[index_of[camera]], -1)
    median_y = margin + plot_height - int(plot_height * np.median([v for _, v in rms]) / top)
    cv2.line(canvas, (margin, median_y), (canvas.shape[1] - margin, median_y), (0, 0, 0), 1)
    cv2.putText(canvas, f"RMS per image (max {top:.3f} px, line = median)", (10, 25),
                cv2.FONT_HERSHEY_SIMPLEX, 0.5, (0, 0, 0), 1, cv2.LINE_AA)
    written.append(imwrite(directory / "per_image_rms.png", canvas))
    return written + write_volume_report(result, directory, board, sigma_maps)


def write_suggestion_preview(camera: Camera, shots, path: str | os.PathLike) -> Path:
    """A frame-sized PNG with each suggested board view (:class:`camcal.geometry.suggest.SuggestedView`)
    drawn as its outline and numbered in the order of the shot list."""
    width, height = camera.image_size
    canvas = np.full((height, width, 3), 40, np.uint8)
    colours = _palette(len(shots))
    for number, (shot, colour) in enumerate(zip(shots, colours), start=1):
        hull = cv2.convexHull(np.round(shot.corners_px).astype(np.int32))
        cv2.polylines(canvas, [hull], True, colour, 2, cv2.LINE_AA)
        for x, y in np.round(shot.corners_px).astype(int):
            cv2.circle(canvas, (int(x), int(y)), 2, colour, -1, cv2.LINE_AA)
        cx, cy = np.round(shot.centre_px).astype(int)
        cv2.putText(canvas, str(number), (int(cx) - 8, int(cy) + 8), cv2.FONT_HERSHEY_SIMPLEX, 0.9, colour, 2,
                    cv2.LINE_AA)
    return imwrite(Path(path), canvas)
