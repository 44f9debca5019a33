"""camcal cameras <-> COLMAP camera models, exactly, without importing pycolmap.

COLMAP differs from camcal in two ways that matter here:

- its pixel (0, 0) is the top-left CORNER, so the centre of the top-left
  pixel is (0.5, 0.5): principal points shift by +0.5 going to COLMAP;
- its distortion parameters act on normalised coordinates
  ``x = (u - cx) / fx``; camcal's ``division`` model acts on pixels. For the
  one-parameter division model ``x_u = x_d / (1 + k r_d^2)`` (COLMAP, r in
  normalised units) and ``x_u = c + (x_d - c) / (1 + lambda r_d^2)`` (camcal,
  r in x pixels, ``r_d^2 = dx^2 + (aspect dy)^2``) are the same lens when
  the centre is the principal point, ``aspect = fx / fy`` and
  ``k = lambda fx^2``.

Exact mappings (camcal -> COLMAP):

==========================  ==============================================
camcal                      COLMAP
==========================  ==============================================
none                        PINHOLE (SIMPLE_PINHOLE when fx = fy)
polynomial k1, k2           RADIAL when fx = fy, else OPENCV (p1 = p2 = 0)
polynomial k1, k2, k3       FULL_OPENCV (p = 0, k4 = k5 = k6 = 0)
opencv (k3 = 0)             OPENCV
opencv (k1..k3[, k4..k6])   FULL_OPENCV (rational k4, k5, k6 as they are)
opencv with s1..s4          none (COLMAP has no pinhole thin prism): refused
division, centre = pp       SIMPLE_DIVISION (fx = fy, aspect 1), DIVISION
                            (aspect = fx / fy)
kannala-brandt k1..k4       OPENCV_FISHEYE (same k1..k4, same normalisation)
kannala-brandt-thin-prism   RAD_TAN_THIN_PRISM_FISHEYE: k0..k5 = k1..k6,
                            p0 = p2, p1 = p1, s0..s3 = s1..s4
==========================  ==============================================

COLMAP -> camcal accepts SIMPLE_PINHOLE, PINHOLE, SIMPLE_RADIAL, RADIAL,
OPENCV, FULL_OPENCV (rational terms included), SIMPLE_DIVISION and DIVISION,
and the Kannala-Brandt family: SIMPLE_FISHEYE and FISHEYE
(equidistant, all k = 0), SIMPLE_RADIAL_FISHEYE (k1), RADIAL_FISHEYE
(k1, k2), OPENCV_FISHEYE (k1..k4) and RAD_TAN_THIN_PRISM_FISHEYE. Anything that has no exact
counterpart is refused with the reason; camcal cameras with skew cannot be
expressed in COLMAP.

COLMAP's fisheye models image only rays in front of the camera (it takes
``x / z``, ``y / z`` and refuses ``z <= 0``); camcal's Kannala-Brandt lenses
also image rays up to its ``max_angle_rad`` (beyond 90 degrees), which
COLMAP cannot carry.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from camcal.base.errors import CamcalError
from camcal.model.camera import K_from_colmap, K_to_colmap
from camcal.model.distortion import Distortion
from camcal.model.rig import Camera

__all__ = ["ColmapCamera", "camera_to_colmap", "camera_from_colmap"]


@dataclass(frozen=True)
class ColmapCamera:
    """A COLMAP camera as model name, size and parameter list (COLMAP's order)."""

    model: str
    width: int
    height: int
    params: tuple[float, ...]


def camera_to_colmap(camera: Camera) -> ColmapCamera:
    """The COLMAP camera that projects exactly like ``camera``.

    Raises
    ------
    CamcalError
        Skew, a lens model COLMAP lacks (3DE's), or a division model off
        the principal point or whose ``aspect`` is not ``fx / fy``.

    Notes
    -----
    A ``kannala-brandt`` camera always becomes ``OPENCV_FISHEYE`` (all four
    coefficients, so a refinement in COLMAP keeps the model's shape).
    """
    K = K_to_colmap(camera.K)
    if K[0, 1] != 0.0:
        raise CamcalError(f"camera {camera.name!r} has skew {K[0, 1]:.3g}: COLMAP's models have none")
    fx, fy, cx, cy = K[0, 0], K[1, 1], K[0, 2], K[1, 2]
    width, height = camera.image_size
    model = camera.distortion.model
    p = camera.distortion.params
    if camera.distortion.has_correction:
        raise CamcalError(f"camera {camera.name!r} has a correction field ({model} + spline): COLMAP's models have "
                          "none (rig export takes its nearest parametric model and prints what it loses)")
    square = fx == fy
    if model == "none":
        if square:
            return ColmapCamera("SIMPLE_PINHOLE", width, height, (fx, cx, cy))
        return ColmapCamera("PINHOLE", width, height, (fx, fy, cx, cy))
    if model == "polynomial" and p.get("k3", 0.0) == 0.0:
        if square:
            return ColmapCamera("RADIAL", width, height, (fx, cx, cy, p["k1"], p["k2"]))
        return ColmapCamera("OPENCV", width, height, (fx, fy, cx, cy, p["k1"], p["k2"], 0.0, 0.0))
    if model in ("polynomial", "opencv"):
        if camera.distortion.opencv_terms > 8:
            raise CamcalError(f"camera {camera.name!r}: COLMAP's pinhole models have no thin-prism terms (s1..s4)")
        k1, k2, p1, p2, k3, k4, k5, k6 = camera.distortion.opencv_coefficients(8)
        if (k3, k4, k5, k6) == (0.0, 0.0, 0.0, 0.0):
            return ColmapCamera("OPENCV", width, height, (fx, fy, cx, cy, k1, k2, p1, p2))
        return ColmapCamera("FULL_OPENCV", width, height, (fx, fy, cx, cy, k1, k2, p1, p2, k3, k4, k5, k6))
    if model == "kannala-brandt":
        return ColmapCamera("OPENCV_FISHEYE", width, height, (fx, fy, cx, cy, p["k1"], p["k2"], p["k3"], p["k4"]))
    if model == "kannala-brandt-thin-prism":
        extra = tuple(p[name] for name in ("k1", "k2", "k3", "k4", "k5", "k6", "p2", "p1", "s1", "s2", "s3", "s4"))
        return ColmapCamera("RAD_TAN_THIN_PRISM_FISHEYE", width, height, (fx, fy, cx, cy) + extra)
    if model != "division":
        raise CamcalError(f"camera {camera.name!r}: COLMAP has no model like camcal's {model!r} (rig export takes "
                          "its nearest COLMAP model and prints what it loses)")
    centre = camera.distortion.center
    if centre is not None and tuple(centre) != (camera.K[0, 2], camera.K[1, 2]):
        raise CamcalError(
            f"camera {camera.name!r}: COLMAP's division model is centred on the principal point, "
            f"the lens centre is at {centre}"
        )
    aspect = p.get("aspect", 1.0)
    if square and aspect == 1.0:
        return ColmapCamera("SIMPLE_DIVISION", width, height, (fx, cx, cy, p["lambda"] * fx * fx))
    if abs(aspect - fx / fy) > 1e-12 * aspect:
        raise CamcalError(
            f"camera {camera.name!r}: COLMAP's division model is round in normalised coordinates, so it needs "
            f"the division aspect = fx / fy = {fx / fy!r} (the lens has aspect {aspect!r})"
        )
    return ColmapCamera("DIVISION", width, height, (fx, fy, cx, cy, p["lambda"] * fx * fx))


def camera_from_colmap(
    name: str,
    model: str,
    image_size: tuple[int, int],
    params: ArrayLike,
    R: ArrayLike,
    c: ArrayLike,
) -> Camera:
    """The camcal camera that projects exactly like a COLMAP camera.

    Parameters
    ----------
    name : str
    model : str
        COLMAP model name (``pycolmap.Camera.model.name``).
    image_size : (int, int)
    params : array_like
        COLMAP's parameter vector, in COLMAP's pixel convention.
    R, c : pose, world -> camera rotation and centre (see
        :func:`camcal.model.camera.from_colmap`).
    """
    params = [float(v) for v in np.asarray(params, dtype=np.float64).ravel()]
    expected = {
        "SIMPLE_PINHOLE": 3, "PINHOLE": 4, "SIMPLE_RADIAL": 4, "RADIAL": 5,
        "OPENCV": 8, "FULL_OPENCV": 12, "SIMPLE_DIVISION": 4, "DIVISION": 5,
        "SIMPLE_FISHEYE": 3, "FISHEYE": 4, "SIMPLE_RADIAL_FISHEYE": 4, "RADIAL_FISHEYE": 5, "OPENCV_FISHEYE": 8,
        "RAD_TAN_THIN_PRISM_FISHEYE": 16,
    }
    if model not in expected:
        raise CamcalError(
            f"COLMAP camera model {model!r} has no camcal counterpart; supported: {', '.join(expected)}"
        )
    if len(params) != expected[model]:
        raise CamcalError(f"COLMAP model {model} takes {expected[model]} parameters, got {len(params)}")
    if model in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL", "SIMPLE_DIVISION",
                 "SIMPLE_FISHEYE", "SIMPLE_RADIAL_FISHEYE", "RADIAL_FISHEYE"):
        fx = fy = params[0]
        cx, cy = params[1], params[2]
        extra = params[3:]
    else:
        fx, fy, cx, cy = params[:4]
        extra = params[4:]
    K = K_from_colmap([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
    if model in ("SIMPLE_PINHOLE", "PINHOLE"):
        distortion = Distortion.none()
    elif model == "SIMPLE_RADIAL":
        distortion = Distortion("polynomial", {"k1": extra[0], "k2": 0.0})
    elif model == "RADIAL":
        distortion = Distortion("polynomial", {"k1": extra[0], "k2": extra[1]})
    elif model == "OPENCV":
        k1, k2, p1, p2 = extra
        distortion = Distortion("opencv", {"k1": k1, "k2": k2, "p1": p1, "p2": p2, "k3": 0.0})
    elif model == "FULL_OPENCV":
        k1, k2, p1, p2, k3, k4, k5, k6 = extra
        distortion = Distortion("opencv", {"k1": k1, "k2": k2, "p1": p1, "p2": p2, "k3": k3}
                                | ({"k4": k4, "k5": k5, "k6": k6} if (k4, k5, k6) != (0.0, 0.0, 0.0) else {}))
    elif model == "RAD_TAN_THIN_PRISM_FISHEYE":
        names = ("k1", "k2", "k3", "k4", "k5", "k6", "p2", "p1", "s1", "s2", "s3", "s4")
        distortion = Distortion("kannala-brandt-thin-prism", dict(zip(names, extra)))
    elif model.endswith("FISHEYE"):
        k = (list(extra) + [0.0, 0.0, 0.0, 0.0])[:4]
        distortion = Distortion("kannala-brandt", {"k1": k[0], "k2": k[1], "k3": k[2], "k4": k[3]})
    else:  # SIMPLE_DIVISION, DIVISION
        aspect = {} if fx == fy else {"aspect": fx / fy}
        distortion = Distortion("division", {"lambda": extra[0] / (fx * fx)} | aspect, center=(K[0, 2], K[1, 2]))
    return Camera(name=name, image_size=image_size, K=K, distortion=distortion, R=R, c=c)
