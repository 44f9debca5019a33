"""The world of a solve set after the fact: up axis, origin, scale and units (``solve --up --origin --scale``),
or all four from a board seen in the images (``solve --world-board``).

The options are read and checked before any work (:func:`world_spec`), then
applied to the refined reconstruction (:func:`align_world`): the similarity
of :func:`camcal.geometry.world_align.world_from_constraints` moves the
COLMAP model, and with it the rig's frames and the sparse points written
beside it. The ground is ``z = 0`` with ``+z`` up, the first camera looks
down ``+y``.

A board (:func:`board_world`) is looked for in up to :data:`BOARD_FRAMES`
registered images spread over the solve; its corners are triangulated
from the solved cameras and the world set on it
(:func:`camcal.geometry.world_align.world_from_board`): its plane the
ground, ``+z`` towards the cameras, its first inner corner the origin, its
columns ``+x``, its square size in the board's units.

A point is named by its row in the solve's ``points.ply`` (0-based: the same
images and command give the same points, so a first solve's PLY names
them for the second) or by its coordinates ``x:y:z`` in the solve's own
world.
"""

from __future__ import annotations

import dataclasses
import re
from dataclasses import dataclass

from pathlib import Path

import cv2
import numpy as np
from numpy.typing import NDArray

from camcal.base.errors import CamcalError
from camcal.geometry.board import Board, detect_board, parse_board
from camcal.geometry.world_align import (Similarity, ground_plane_RANSAC, mean_camera_up, point_under,
                                         world_from_board, world_from_constraints)
from camcal.io.frames import imread
from camcal.model.quality import ParameterCovariance
from camcal.model.rig import Rig

__all__ = ["BOARD_FRAMES", "UP_SOURCES", "WorldAlignment", "WorldSpec", "align_world", "board_world",
           "scaled_translations", "world_spec"]

#: where ``--up`` comes from: the ground plane of the sparse points, or the cameras' mean up.
UP_SOURCES = ("ground", "cameras")

#: the registered images searched for ``--world-board`` at most (evenly spread over the solve): the board's
#: corners need two views, and a few more average their noise; detection costs 0.1-0.6 s a frame at 4K.
BOARD_FRAMES = 24

_NUMBER = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
_POINT = re.compile(rf"^\s*(?:(?P<index>\d+)|(?P<xyz>{_NUMBER}:{_NUMBER}:{_NUMBER}))\s*$")


@dataclass(frozen=True)
class WorldSpec:
    """What ``--up``, ``--origin``, ``--scale`` and ``--units`` asked for, checked.

    Attributes
    ----------
    up : {"ground", "cameras"} or None
    origin : str or int or ndarray or None
        ``"ground"`` (the ground under the first camera), a point row, or coordinates.
    scale : (point, point, float) or None
        Two points (rows or coordinates) and their distance.
    units : str or None
        The units of that distance or of the board's squares (the rig's ``units``).
    board : Board or None
        A board seen in the images that sets up, origin and scale at once.
    """

    up: str | None = None
    origin: str | int | NDArray[np.float64] | None = None
    scale: tuple[int | NDArray[np.float64], int | NDArray[np.float64], float] | None = None
    units: str | None = None
    board: Board | None = None

    @property
    def active(self) -> bool:
        """Whether anything is to be moved."""
        return self.up is not None or self.origin is not None or self.scale is not None or self.board is not None


@dataclass(frozen=True)
class WorldAlignment:
    """A solve's world as set (:func:`align_world`, :func:`board_world`).

    Attributes
    ----------
    similarity : Similarity
        Reconstruction -> the set's world.
    lines : tuple of str
        What was done, one line per constraint.
    up_sigma_deg : float or None
        The up axis's one-sigma tilt (degrees, the RMS angle of its error) when the ground plane set it: its
        normal's uncertainty from its points' spread off it
        (:attr:`camcal.geometry.world_align.GroundPlane.tilt_sigma_deg`), relative to the solve's points. A
        camera's pointing has its own uncertainty on top (its principal point's: a shift of ``d`` pixels turns it
        by about ``d / f``).
    """

    similarity: Similarity
    lines: tuple[str, ...]
    up_sigma_deg: float | None = None

    def record(self) -> dict:
        """The rig provenance's ``world`` entry: ``notes`` (the lines) and, when known, ``up_sigma_deg``."""
        return {"notes": list(self.lines),
                **({} if self.up_sigma_deg is None else {"up_sigma_deg": self.up_sigma_deg})}


def _point(text: str, option: str) -> int | NDArray[np.float64]:
    match = _POINT.match(text)
    if match is None:
        raise CamcalError(f"{option} {text!r}: a point is its row in points.ply (e.g. 12) or its coordinates x:y:z "
                          "(e.g. 0.5:-1.2:3)")
    if match["index"] is not None:
        return int(match["index"])
    return np.array([float(v) for v in match["xyz"].split(":")])


def world_spec(up: str | None = None, origin: str | None = None, scale: str | None = None,
               units: str | None = None, board: str | Board | None = None) -> WorldSpec:
    """Read the world options (before any work, so that a typo costs nothing).

    Parameters
    ----------
    up : {"ground", "cameras"}, optional
    origin : str, optional
        ``ground``, a point row (``12``) or coordinates (``0.5:-1.2:3``).
    scale : str, optional
        ``A,B=DIST``: two points (rows or coordinates) and their distance, e.g. ``12,40=1.5``.
    units : str, optional
        The distance's (or the board's square size's) unit (default ``m`` with ``scale`` or ``board``); the rig's
        ``units``.
    board : str or Board, optional
        A board spec (:func:`camcal.geometry.board.parse_board`, e.g. ``chessboard:9x6:0.04``) seen in the images:
        it sets the up axis, origin and scale, so none of ``up``, ``origin``, ``scale`` may be given with it.
    """
    if board is not None:
        given = [name for name, value in (("--up", up), ("--origin", origin), ("--scale", scale)) if value is not None]
        if given:
            raise CamcalError(f"--world-board sets the up axis, the origin and the scale from the board: give it "
                              f"without {' and '.join(given)}")
        board = board if isinstance(board, Board) else parse_board(board)
    if up is not None and up not in UP_SOURCES:
        raise CamcalError(f"unknown --up {up!r}, expected one of: {', '.join(UP_SOURCES)}")
    where = None
    if origin is not None:
        where = "ground" if origin.strip() == "ground" else _point(origin, "--origin")
    pair = None
    if scale is not None:
        left, equals, distance = scale.partition("=")
        points = left.split(",")
        if not equals or len(points) != 2:
            raise CamcalError(f"--scale {scale!r}: expected A,B=DISTANCE, e.g. 12,40=1.5 (two points of points.ply "
                              "or x:y:z coordinates, and their distance)")
        try:
            length = float(distance)
        except ValueError:
            raise CamcalError(f"--scale {scale!r}: the distance {distance!r} is not a number") from None
        if not (np.isfinite(length) and length > 0):
            raise CamcalError(f"--scale {scale!r}: the distance must be positive")
        pair = (_point(points[0], "--scale"), _point(points[1], "--scale"), length)
    if units is not None and pair is None and board is None:
        raise CamcalError(f"--units {units!r} names the unit of --scale's distance or of --world-board's squares: "
                          "give --scale or --world-board too")
    if units is not None and not units.strip():
        raise CamcalError("--units must not be empty")
    return WorldSpec(up, where, pair, (units or "m") if pair is not None or board is not None else None, board)


def _where(point: int | NDArray[np.float64], xyz: NDArray[np.float64], option: str) -> NDArray[np.float64]:
    if isinstance(point, int):
        if point >= len(xyz):
            raise CamcalError(f"{option}: point {point} does not exist: the solve has {len(xyz)} points "
                              f"(rows 0-{len(xyz) - 1} of points.ply)")
        return xyz[point]
    return point


def align_world(xyz: NDArray[np.float64], rotations: NDArray[np.float64], centres: NDArray[np.float64],
                spec: WorldSpec, seed: int = 0) -> WorldAlignment:
    """The similarity that puts a solve in the set's world, what it did in words and the up axis's sigma.

    Parameters
    ----------
    xyz : ndarray, shape (P, 3)
        The sparse points, in the order of ``points.ply``.
    rotations, centres : ndarray, shapes (M, 3, 3), (M, 3)
        The registered images' ``R`` (world -> camera) and centres, the
        first camera's first frame first (its view sets the heading).
    spec : WorldSpec
    seed : int
        Seeds the ground plane's RANSAC.

    Returns
    -------
    WorldAlignment
        ``X_new = s R X + t``, one line per constraint, and with ``up="ground"`` the up axis's sigma.
    """
    lines = []
    plane = None
    if spec.up == "ground" or spec.origin == "ground":
        plane = ground_plane_RANSAC(xyz, cameras=centres, seed=seed, up_hint=mean_camera_up(rotations))
        lines.append(f"ground plane: {int(plane.inliers.sum())} of {len(xyz)} points within {plane.threshold:.3g} "
                     "(RANSAC)")
    up, up_sigma_deg = None, None
    if spec.up == "ground":
        up, up_sigma_deg = plane.normal, plane.tilt_sigma_deg
        lines.append(f"up: the ground plane's normal (+z, +- {up_sigma_deg:.2g} deg at 1 sigma from its points' "
                     "spread), the first camera looking down +y")
    elif spec.up == "cameras":
        up = mean_camera_up(rotations)
        lines.append(f"up: the mean up of {len(rotations)} cameras (+z), the first camera looking down +y")
    origin = None
    if spec.origin == "ground":
        origin = point_under(plane, centres[0])
        lines.append("origin: the ground under the first camera")
    elif spec.origin is not None:
        origin = _where(spec.origin, xyz, "--origin")
        lines.append(f"origin: {_named(spec.origin)}")
    scale = None
    if spec.scale is not None:
        A, B, distance = spec.scale
        scale = (_where(A, xyz, "--scale"), _where(B, xyz, "--scale"), distance)
    similarity = world_from_constraints(up, rotations[0][2], origin, scale)
    if scale is not None:
        lines.append(f"scale: {_named(spec.scale[0])} to {_named(spec.scale[1])} = {spec.scale[2]:g} {spec.units} "
                     f"(x {similarity.s:.6g})")
    return WorldAlignment(similarity, tuple(lines), up_sigma_deg)


def board_world(reconstruction, image_dir: Path, board: Board, units: str, seed: int = 0,
                max_frames: int = BOARD_FRAMES) -> WorldAlignment:
    """The similarity that sets a solve's world on a board seen in its images, and what it did in words (no up
    sigma: the board's pose is fitted to its corners' rays, :func:`camcal.geometry.world_align.world_from_board`).

    Parameters
    ----------
    reconstruction : pycolmap.Reconstruction
        The refined solve (its registered images' poses and cameras).
    image_dir : Path
        The folder its image names are relative to (the solve's staged images).
    board : Board
    units : str
        The unit of the board's square size (said).
    seed : int
        Seeds the fit's search (:func:`camcal.geometry.world_align.world_from_board`).
    max_frames : int
        Registered images searched at most, evenly spread in name order.

    Raises
    ------
    CamcalError
        The board found in fewer than two of the images searched, or fewer than three of its corners (not on
        one line) in two of them.
    """
    images = sorted((image for image in reconstruction.images.values() if image.has_pose), key=lambda im: im.name)
    if len(images) > max_frames:
        images = [images[k] for k in np.linspace(0, len(images) - 1, max_frames).round().astype(int)]
    rotations, translations, ids, rays, found = [], [], [], [], []
    for image in images:
        detection = detect_board(board, imread(image_dir / image.name, cv2.IMREAD_GRAYSCALE), image.name)
        if detection is None:
            continue
        pose = image.cam_from_world()
        rotations.append(pose.rotation.matrix())
        translations.append(np.asarray(pose.translation))
        ids.append(detection.ids)
        # camcal's pixel (0, 0) is the centre of the top-left pixel, COLMAP's is its corner
        rays.append(np.asarray(reconstruction.cameras[image.camera_id].cam_from_img(detection.corners_px + 0.5)))
        found.append(image.name)
    if len(found) < 2:
        where = "in none" if not found else f"only in {found[0]}"
        raise CamcalError(f"--world-board {board.spec()}: the board was found {where} of the {len(images)} frames "
                          "searched; its corners need two views")
    fit = world_from_board(board.object_points, np.array(rotations), np.array(translations), ids, rays, seed=seed)
    lines = [f"world board: {board.spec()} found in {len(found)} of {len(images)} frames searched, "
             f"{fit.n_corners} of {board.n_corners} corners fitted, triangulated within {fit.rms:.3g} {units} RMS",
             "up: the board's normal (+z, towards the cameras); origin: its first inner corner; +x along its columns",
             f"scale: the board's squares = {board.square:g} {units} (x {fit.similarity.s:.6g})"]
    return WorldAlignment(fit.similarity, tuple(lines))


def _named(point: int | NDArray[np.float64]) -> str:
    if isinstance(point, int):
        return f"point {point}"
    return "(" + ", ".join(f"{v:g}" for v in point) + ")"


def scaled_translations(rig: Rig, s: float) -> Rig:
    """The rig's fit quality after its world was scaled by ``s``: the covariance rows of translations
    (``tx``, ``ty``, ``tz``, any camera's) scale by ``s`` (the poses themselves were moved with the model)."""
    if s == 1.0:
        return rig
    cameras = []
    for camera in rig.cameras:
        covariance = camera.quality.covariance if camera.quality else None
        if covariance is None:
            cameras.append(camera)
            continue
        factor = [s if name.rsplit(".", 1)[-1].removeprefix("gauge_") in ("tx", "ty", "tz") else 1.0
                  for name in covariance.names]
        scaled = ParameterCovariance(covariance.names, covariance.array * np.outer(factor, factor))
        cameras.append(dataclasses.replace(camera, quality=dataclasses.replace(camera.quality, covariance=scaled)))
    return dataclasses.replace(rig, cameras=tuple(cameras))
