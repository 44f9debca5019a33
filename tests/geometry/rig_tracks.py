"""Synthetic tracks of a moving rig for the bundle-adjustment tests: each camera's projections of points plus noise."""

import numpy as np

from camcal.model.rig import Camera


def observe_points(cameras, poses, X, rng, noise_px: float):
    """Every point of ``X`` (N, 3) seen by each camera of the rig at each pose ``(R_rig, c_rig)``: in front
    (depth > 0.3) and inside the image, with Gaussian noise of ``noise_px``.

    Returns the observations' camera index, frame index, point index (arrays) and their pixels (M, 2).
    """
    cams, frames, points, xys = [], [], [], []
    for f, (R_rig, c_rig) in enumerate(poses):
        for k, camera in enumerate(cameras):
            posed = Camera(camera.name, camera.image_size, camera.K, camera.distortion, camera.R @ R_rig,
                           c_rig + R_rig.T @ camera.c)
            depth = (X - posed.c) @ posed.R[2]
            with np.errstate(invalid="ignore"):
                xy = posed.project(X)
            inside = np.all((xy > 0) & (xy < np.array(camera.image_size) - 1), axis=1)
            index = np.flatnonzero((depth > 0.3) & np.all(np.isfinite(xy), axis=1) & inside)
            cams += [k] * len(index)
            frames += [f] * len(index)
            points += list(index)
            xys.append(xy[index] + rng.normal(0.0, noise_px, (len(index), 2)))
    return np.array(cams), np.array(frames), np.array(points), np.vstack(xys)
