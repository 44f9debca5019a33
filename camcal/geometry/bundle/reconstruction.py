"""A :class:`~camcal.geometry.bundle.state.BundleState` from and into a pycolmap ``Reconstruction``.

Pixels move between COLMAP's convention (pixel centre 0.5) and camcal's (0)
here (:func:`camcal.model.camera.pixels_from_colmap`).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from camcal.base.errors import CamcalError
from camcal.base.extras import require
from camcal.geometry.bundle.state import BundleState
from camcal.model.camera import pixels_from_colmap, pixels_to_colmap

__all__ = ["image_observations", "observations_to_reconstruction", "state_from_reconstruction",
           "state_images", "state_to_reconstruction"]


def state_from_reconstruction(reconstruction, camera_names: dict[int, str] | None = None) -> BundleState:
    """A :class:`BundleState` from a pycolmap ``Reconstruction`` with one rig, or with one camera per rig.

    ``camera_names`` maps COLMAP camera ids to names (default ``camera<id>``);
    the rig's reference sensor becomes camera 0. Pixels move from COLMAP's
    convention (pixel centre 0.5) to camcal's (0). Several rigs of one camera
    each (a lens per frame: one camera per image) share the identity as their
    ``sensor_from_rig``: hold it (``refine_sensor_from_rig=False``).
    """
    pycolmap = require("pycolmap")

    rig = _the_rig(reconstruction)
    camera_ids = _camera_order(reconstruction)
    names = camera_names or {cid: f"camera{cid}" for cid in camera_ids}
    sensor_R = np.repeat(np.eye(3)[None], len(camera_ids), axis=0)
    sensor_t = np.zeros((len(camera_ids), 3))
    for index, cid in enumerate(camera_ids[1:] if reconstruction.num_rigs() == 1 else [], start=1):
        pose = rig.sensor_from_rig(pycolmap.sensor_t(pycolmap.SensorType.CAMERA, cid))
        sensor_R[index], sensor_t[index] = pose.rotation.matrix(), pose.translation
    frame_ids = sorted(reconstruction.reg_frame_ids())
    frame_R = np.array([reconstruction.frame(fid).rig_from_world.rotation.matrix() for fid in frame_ids])
    frame_t = np.array([reconstruction.frame(fid).rig_from_world.translation for fid in frame_ids])
    point_ids = sorted(reconstruction.points3D)
    sorted_ids = np.array(point_ids, dtype=np.int64)
    # image by image, its observations in keypoint order
    cams, frames, pts, xys = [np.zeros(0, np.int64)], [np.zeros(0, np.int64)], [np.zeros(0, np.int64)], [np.zeros((0, 2))]
    for image, (camera, frame) in _posed_images(reconstruction):
        which, xy = image_observations(image, sorted_ids)
        cams.append(np.full(len(which), camera, dtype=np.int64))
        frames.append(np.full(len(which), frame, dtype=np.int64))
        pts.append(which)
        xys.append(xy)
    cameras = [reconstruction.cameras[cid] for cid in camera_ids]
    return BundleState(
        camera_names=tuple(names[cid] for cid in camera_ids),
        models=tuple(c.model.name for c in cameras),
        image_sizes=tuple((c.width, c.height) for c in cameras),
        params=tuple(np.array(c.params, dtype=np.float64) for c in cameras),
        sensor_R=sensor_R, sensor_t=sensor_t, frame_R=frame_R, frame_t=frame_t, frame_ids=tuple(frame_ids),
        points=np.array([reconstruction.points3D[pid].xyz for pid in point_ids]).reshape(-1, 3),
        point_ids=tuple(point_ids),
        obs_camera=np.concatenate(cams), obs_frame=np.concatenate(frames),
        obs_point=np.concatenate(pts),
        obs_xy=pixels_from_colmap(np.concatenate(xys)),
    )


def _camera_order(reconstruction) -> list[int]:
    """COLMAP camera ids in a state's camera order: the rig's reference sensor first, then by id."""
    ref = _the_rig(reconstruction).ref_sensor_id.id
    return [ref] + sorted(cid for cid in reconstruction.cameras if cid != ref)


def _posed_images(reconstruction):
    """Each posed image of a registered frame with its (camera, frame) indices in a state, in the state's order."""
    camera_pos = {cid: k for k, cid in enumerate(_camera_order(reconstruction))}
    frame_pos = {fid: k for k, fid in enumerate(sorted(reconstruction.reg_frame_ids()))}
    for image in reconstruction.images.values():
        if image.has_pose and image.frame_id in frame_pos:
            yield image, (camera_pos[image.camera_id], frame_pos[image.frame_id])


def state_images(reconstruction) -> dict[tuple[int, int], str]:
    """The image name of each (camera, frame) of :func:`state_from_reconstruction`'s state."""
    return {key: image.name for image, key in _posed_images(reconstruction)}


def observations_to_reconstruction(state: BundleState, reconstruction) -> None:
    """Write a state's observed pixels (``obs_xy``, moved by :func:`camcal.geometry.track_refine.refine_tracks`)
    into the keypoints of the pycolmap ``Reconstruction`` it came from (in place), in the order
    :func:`state_from_reconstruction` read them."""
    xy = pixels_to_colmap(state.obs_xy)
    done = 0
    for image, _ in _posed_images(reconstruction):
        points2D = image.points2D
        for index, point in enumerate(points2D):
            if point.has_point3D():
                points2D[index].xy = xy[done]
                done += 1
    if done != len(xy):
        raise CamcalError(f"the state has {len(xy)} observations, the reconstruction {done}: not the state's source")


def image_observations(image, point_ids: NDArray[np.int64]) -> tuple[NDArray[np.int64], NDArray[np.float64]]:
    """A pycolmap image's observations of 3D points in keypoint order: each one's position in ``point_ids`` (the
    reconstruction's point ids, ascending) and its keypoint (COLMAP's pixels, shape (n, 2))."""
    observed = image.get_observation_points2D()
    which = np.searchsorted(point_ids, np.array([point.point3D_id for point in observed], dtype=np.int64))
    return which, np.array([point.xy for point in observed], dtype=np.float64).reshape(-1, 2)


def state_to_reconstruction(state: BundleState, reconstruction) -> None:
    """Write a refined state back into the pycolmap ``Reconstruction`` it came from (in place)."""
    pycolmap = require("pycolmap")

    rig = _the_rig(reconstruction)
    camera_ids = _camera_order(reconstruction)
    for index, cid in enumerate(camera_ids):
        reconstruction.cameras[cid].params = state.params[index]
        if index and reconstruction.num_rigs() == 1:
            rig.set_sensor_from_rig(pycolmap.sensor_t(pycolmap.SensorType.CAMERA, cid),
                                    pycolmap.Rigid3d(pycolmap.Rotation3d(state.sensor_R[index]), state.sensor_t[index]))
    for k, fid in enumerate(state.frame_ids):
        reconstruction.frame(fid).rig_from_world = pycolmap.Rigid3d(
            pycolmap.Rotation3d(state.frame_R[k]), state.frame_t[k])
    for k, pid in enumerate(state.point_ids):
        reconstruction.points3D[pid].xyz = state.points[k]


def _the_rig(reconstruction):
    """The reconstruction's one rig, or the first of several rigs of one camera each (their sensor is their origin)."""
    rigs = list(reconstruction.rigs.values())
    if len(rigs) != 1 and not all(rig.num_sensors() == 1 for rig in rigs):
        raise CamcalError(f"expected one rig in the reconstruction, got {len(rigs)}")
    return min(rigs, key=lambda rig: rig.ref_sensor_id.id)
