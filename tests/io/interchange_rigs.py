"""Rigs the interchange tests export and read back: built here with known cameras."""

import numpy as np
from scipy.spatial.transform import Rotation

from camcal.model.camera import look_at
from camcal.model.distortion import Distortion
from camcal.geometry.rectify import rectify_calibrated
from camcal.io.ply import write_points_ply
from camcal.model.rig import Camera, Frame, Rig, make_provenance

SIZE = (1280, 720)
BROWN = Distortion("opencv", {"k1": -0.12, "k2": 0.03, "p1": 1e-4, "p2": -2e-4, "k3": -0.004})
RADTAN = Distortion("opencv", {"k1": -0.11, "k2": 0.025, "p1": 2e-4, "p2": -1e-4, "k3": 0.0})
FISHEYES = (Distortion("kannala-brandt", {"k1": 0.021, "k2": -0.006, "k3": 0.0012, "k4": -0.0002}),
            Distortion("kannala-brandt", {"k1": 0.018, "k2": -0.004, "k3": 0.0007, "k4": -0.0001}))


def K(fx, fy, cx, cy, skew=0.0):
    return np.array([[fx, skew, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])


def stereo_rig(distortion=BROWN, rectified=True) -> Rig:
    """A 0.25 m stereo pair, slightly toed in and rolled, principal points off centre."""
    R_left = Rotation.from_euler("xyz", [0.4, -1.1, 0.3], degrees=True).as_matrix()
    R_right = Rotation.from_euler("xyz", [-0.3, 0.9, -0.5], degrees=True).as_matrix()
    left = Camera("left", SIZE, K(1010.0, 1008.0, 652.3, 351.7), distortion, R_left, [0.0, 0.0, 0.0])
    right = Camera("right", SIZE, K(1022.0, 1019.5, 631.9, 366.2), distortion, R_right, [0.25, 0.004, -0.002])
    rig = Rig((left, right), units="m", provenance=make_provenance("test"))
    return rectify_calibrated(rig).rig if rectified else rig


def fisheye_rig(rectified=True) -> Rig:
    """A 0.12 m pair of Kannala-Brandt fisheyes (about 150 deg across the diagonal), toed in and rolled."""
    R_left = Rotation.from_euler("xyz", [0.4, -1.1, 0.3], degrees=True).as_matrix()
    R_right = Rotation.from_euler("xyz", [-0.3, 0.9, -0.5], degrees=True).as_matrix()
    left = Camera("left", SIZE, K(560.0, 558.0, 645.2, 357.9), FISHEYES[0], R_left, [0.0, 0.0, 0.0])
    right = Camera("right", SIZE, K(566.0, 565.0, 633.1, 365.4), FISHEYES[1], R_right, [0.12, 0.002, -0.001])
    rig = Rig((left, right), units="m", provenance=make_provenance("test"))
    return rectify_calibrated(rig).rig if rectified else rig


def division_rig() -> Rig:
    """One camera with a Strand-Hayman division lens off the principal point and skew: lossy everywhere."""
    camera = Camera("wide", SIZE, K(900.0, 905.0, 641.0, 362.0, skew=0.8),
                    Distortion("division", {"lambda": -2.4e-7}, center=(630.0, 355.0)),
                    np.eye(3), np.zeros(3))
    return Rig((camera,), units="m", provenance=make_provenance("test"))


def moving_rig(folder) -> tuple[Rig, object]:
    """A two-camera rig over 5 frames with sparse points in a sibling PLY; returns (rig, rig path)."""
    rng = np.random.default_rng(11)
    left = Camera("left", SIZE, K(1100.0, 1100.0, 639.5, 359.5), RADTAN, np.eye(3), np.zeros(3), sensor_width_mm=36.0)
    R_right = Rotation.from_euler("y", -2.0, degrees=True).as_matrix()
    right = Camera("right", SIZE, K(1100.0, 1100.0, 639.5, 359.5), RADTAN, R_right, [0.3, 0.0, 0.0],
                   sensor_width_mm=36.0)
    frames = []
    for index in range(5):
        centre = np.array([4.0 * np.cos(0.2 * index), 4.0 * np.sin(0.2 * index), 1.5])
        frames.append(Frame(1001 + index, look_at(centre, [0.0, 0.0, 0.5]), centre))
    points = rng.uniform(-1.0, 1.0, (200, 3)) + [0.0, 0.0, 0.5]
    write_points_ply(folder / "points.ply", points, rng.integers(0, 256, (200, 3)))
    rig = Rig((left, right), units="m", frames=tuple(frames), points="points.ply", provenance=make_provenance("test"))
    return rig, rig.save(folder / "moving.rig.json")


def world_points(rig: Rig, camera: Camera, n=400, seed=3):
    """Points in front of ``camera`` (rig coordinates) that it sees inside its frame."""
    rng = np.random.default_rng(seed)
    width, height = camera.image_size
    pixels = rng.uniform([5, 5], [width - 6, height - 6], (n, 2))
    ideal = camera.distortion.undistort(pixels, camera.K)
    rays = np.column_stack([ideal, np.ones(n)]) @ np.linalg.inv(camera.K).T
    depth = rng.uniform(1.5, 8.0, (n, 1))
    return (rays * depth) @ camera.R + camera.c, pixels


def relative_projection_error(rig: Rig, back: Rig) -> float:
    """Max px between two rigs' projections of the same points, their first cameras taken as the common frame."""
    worst = 0.0
    ref_a, ref_b = rig.cameras[0], back.cameras[0]
    for a, b in zip(rig.cameras, back.cameras):
        X, _ = world_points(rig, a)
        X_b = (X - ref_a.c) @ ref_a.R.T @ ref_b.R + ref_b.c  # rig a's world -> rig b's world
        worst = max(worst, float(np.abs(a.project(X) - b.project(X_b)).max()))
    return worst


def zoom_rig(camera: Camera, zooms=(1.0, 1.18, 1.35), scale_lens=None, first_frame=1001, drift=(2.0, -1.0),
             state=lambda i, zoom: (24.0 * zoom, 2.0 + i)) -> Rig:
    """``camera`` over ``len(zooms)`` frames of a dolly, zoomed by each factor: one frame per zoom.

    Frame ``first_frame + i`` has a lens (:class:`camcal.model.rig.Lens`) with
    ``fx, fy`` times ``zooms[i]``, the principal point moved by ``i drift``
    px, and the distortion ``scale_lens(distortion, zoom)`` (default: the
    camera's own); its lens state ``(focal_mm, focus_m)`` is ``state(i,
    zoom)`` (default ``24 zoom``, ``2 + i``). The first frame, at zoom 1,
    keeps the camera's own lens (no lens entry) when ``zooms[0] == 1``.
    """
    from camcal.model.rig import Lens

    frames = []
    for i, zoom in enumerate(zooms):
        centre = np.array([0.3 * i, -2.0 + 0.1 * i, 1.2])
        K_frame = camera.K.copy()
        K_frame[0, 0] *= zoom
        K_frame[1, 1] *= zoom
        K_frame[0, 2] += drift[0] * i
        K_frame[1, 2] += drift[1] * i
        distortion = camera.distortion if scale_lens is None else scale_lens(camera.distortion, zoom)
        focal_mm, focus_m = state(i, zoom)
        lenses = {} if zoom == 1.0 and i == 0 else {
            camera.name: Lens(K_frame, distortion, focal_mm=focal_mm, focus_m=focus_m)}
        frames.append(Frame(first_frame + i, look_at(centre, [0.0, 4.0, 1.0]), centre, lenses=lenses))
    return Rig((camera,), units="m", frames=tuple(frames), provenance=make_provenance("test"))
