"""camcal camera parameters -> Blender settings, in plain Python.

No bpy, no numpy: the conversion maths runs and is tested outside Blender.
Matrices are tuples or lists of rows.

Conventions
-----------
camcal (DESIGN.md): ``x ~ K [R | -R c] X``; ``R`` rotates world to camera;
camera axes x right, y down, z forward; pixel (0, 0) is the *centre* of the
top-left pixel.

Blender: the camera looks down -Z with +Y up, so the world-to-camera
rotation in Blender's camera axes is ``R_blender = diag(1, -1, -1) @ R`` and
the camera object's world matrix is ``[[R_blender^T, c], [0, 0, 0, 1]]``.
Blender measures shifts and the tracking principal point from the image
*edges* (the tracking camera from the bottom-left corner, y up).

Intrinsics (checked against ``Object.calc_matrix_camera`` on bpy 5.0.1):
pixel aspect ``ax / ay = fy / fx`` (the smaller one is 1);
``ycor = ay / ax``; the effective sensor fit is horizontal when
``W * ax >= H * ay`` (AUTO) or as set; ``viewfac = W`` (horizontal) or
``H * ycor`` (vertical); ``lens = fx * sensor / viewfac`` with ``sensor`` the
sensor height for a VERTICAL fit and the sensor width otherwise (AUTO always
uses the width); ``shift_x = (W / 2 - (cx + 0.5)) / viewfac``;
``shift_y = ((cy + 0.5) - H / 2) * ycor / viewfac``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = [
    "CV_TO_BLENDER_CAMERA",
    "UP_AXES",
    "BlenderIntrinsics",
    "BlenderLens",
    "blender_intrinsics",
    "intrinsics_from_blender",
    "camera_rotation_blender",
    "camera_matrix_local",
    "up_axis_matrix",
    "rig_matrix",
    "rectified_camera",
    "overscan_margins",
    "BLENDER_MODELS",
    "EXACT_MODELS",
    "blender_lens",
    "blender_distort",
    "solve_linear",
    "division_distort",
    "division_undistort",
    "polynomial_distort",
    "polynomial_undistort",
    "opencv_distort",
    "distort",
    "to_blender_pixel",
    "from_blender_pixel",
    "relative_pose",
    "is_parallel_pair",
    "matmul",
    "transpose",
    "inverse3",
]

CV_TO_BLENDER_CAMERA = ((1.0, 0.0, 0.0), (0.0, -1.0, 0.0), (0.0, 0.0, -1.0))

# camcal world axis that becomes Blender's +Z (up), as a rotation world -> Blender world.
UP_AXES = {
    "Z": ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0)),
    "Y": ((1.0, 0.0, 0.0), (0.0, 0.0, -1.0), (0.0, 1.0, 0.0)),
    "-Y": ((1.0, 0.0, 0.0), (0.0, 0.0, 1.0), (0.0, -1.0, 0.0)),
}

SENSOR_FITS = ("AUTO", "HORIZONTAL", "VERTICAL")


# --------------------------------------------------------------------------
# Small matrix helpers (3x3 and 4x4 as nested tuples).


def matmul(A, B):
    """Matrix product of two nested sequences."""
    return tuple(
        tuple(sum(A[i][k] * B[k][j] for k in range(len(B))) for j in range(len(B[0])))
        for i in range(len(A))
    )


def transpose(A):
    """Transpose of a nested sequence."""
    return tuple(tuple(A[i][j] for i in range(len(A))) for j in range(len(A[0])))


def _det3(A):
    return (
        A[0][0] * (A[1][1] * A[2][2] - A[1][2] * A[2][1])
        - A[0][1] * (A[1][0] * A[2][2] - A[1][2] * A[2][0])
        + A[0][2] * (A[1][0] * A[2][1] - A[1][1] * A[2][0])
    )


def inverse3(A):
    """Inverse of a 3x3 matrix (cofactors); ``ValueError`` if singular."""
    det = _det3(A)
    if det == 0:
        raise ValueError("singular 3x3 matrix")
    cof = [[0.0] * 3 for _ in range(3)]
    for i in range(3):
        for j in range(3):
            rows = [r for r in range(3) if r != i]
            cols = [c for c in range(3) if c != j]
            minor = A[rows[0]][cols[0]] * A[rows[1]][cols[1]] - A[rows[0]][cols[1]] * A[rows[1]][cols[0]]
            cof[i][j] = (-1) ** (i + j) * minor
    return tuple(tuple(cof[j][i] / det for j in range(3)) for i in range(3))


# --------------------------------------------------------------------------
# Intrinsics.


@dataclass(frozen=True)
class BlenderIntrinsics:
    """Blender camera and render settings that reproduce a pinhole ``K``.

    ``sensor_fit`` is what to set on the camera (as requested);
    ``effective_fit`` is the fit Blender then uses (HORIZONTAL or VERTICAL).
    ``skew`` is the skew of ``K``, which Blender cannot represent.
    """

    resolution_x: int
    resolution_y: int
    pixel_aspect_x: float
    pixel_aspect_y: float
    sensor_fit: str
    effective_fit: str
    sensor_width: float
    sensor_height: float
    lens: float
    shift_x: float
    shift_y: float
    skew: float


def _fit(W, H, ax, ay, sensor_fit):
    """Blender's effective sensor fit and ``viewfac`` (pixels across the fitted sensor side)."""
    if sensor_fit == "AUTO":
        effective = "HORIZONTAL" if W * ax >= H * ay else "VERTICAL"
    else:
        effective = sensor_fit
    return effective, (W if effective == "HORIZONTAL" else H * ay / ax)


def blender_intrinsics(K, image_size, sensor_width_mm=36.0, sensor_fit="AUTO"):
    """Blender settings that project like the pinhole ``K`` on ``image_size``.

    Parameters
    ----------
    K : 3x3 nested sequence
        ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]`` in pixels, pixel centres at
        integers (camcal's convention).
    image_size : (int, int)
        Width and height in pixels.
    sensor_width_mm : float
        Physical sensor width; the sensor height follows from the pixel grid.
    sensor_fit : {'AUTO', 'HORIZONTAL', 'VERTICAL'}
        The camera's sensor fit; every choice is exact.

    Returns
    -------
    BlenderIntrinsics

    Notes
    -----
    Blender projects with ``fx = lens * viewfac / sensor`` and
    ``fy = fx * ax / ay``; the principal point sits at
    ``W / 2 - shift_x * viewfac`` from the left edge and
    ``H / 2 + shift_y * viewfac / ycor`` from the top edge, i.e. at
    ``cx + 0.5`` and ``cy + 0.5`` in edge coordinates.
    """
    if sensor_fit not in SENSOR_FITS:
        raise ValueError(f"sensor_fit: unknown {sensor_fit!r}, expected one of: {', '.join(SENSOR_FITS)}")
    W, H = int(image_size[0]), int(image_size[1])
    fx, skew, cx = float(K[0][0]), float(K[0][1]), float(K[0][2])
    fy, cy = float(K[1][1]), float(K[1][2])
    if not (fx > 0 and fy > 0):
        raise ValueError(f"focal lengths must be positive, got fx={fx}, fy={fy}")
    if fy >= fx:
        ax, ay = fy / fx, 1.0
    else:
        ax, ay = 1.0, fx / fy
    ycor = ay / ax
    effective, viewfac = _fit(W, H, ax, ay, sensor_fit)
    sensor_w = float(sensor_width_mm)
    # The sensor height that keeps the physical pixel pitch of the width.
    sensor_h = sensor_w * H * ycor / W
    sensor = sensor_h if sensor_fit == "VERTICAL" else sensor_w
    return BlenderIntrinsics(
        resolution_x=W,
        resolution_y=H,
        pixel_aspect_x=ax,
        pixel_aspect_y=ay,
        sensor_fit=sensor_fit,
        effective_fit=effective,
        sensor_width=sensor_w,
        sensor_height=sensor_h,
        lens=fx * sensor / viewfac,
        shift_x=(W / 2.0 - (cx + 0.5)) / viewfac,
        shift_y=((cy + 0.5) - H / 2.0) * ycor / viewfac,
        skew=skew,
    )


def intrinsics_from_blender(b):
    """The ``K`` (pixel centres at integers) that Blender settings ``b`` project with.

    The inverse of :func:`blender_intrinsics` (without skew), for checks.
    """
    W, H = b.resolution_x, b.resolution_y
    ax, ay = b.pixel_aspect_x, b.pixel_aspect_y
    ycor = ay / ax
    viewfac = _fit(W, H, ax, ay, b.sensor_fit)[1]
    sensor = b.sensor_height if b.sensor_fit == "VERTICAL" else b.sensor_width
    fx = b.lens * viewfac / sensor
    fy = fx * ax / ay
    cx = W / 2.0 - b.shift_x * viewfac - 0.5
    cy = H / 2.0 + b.shift_y * viewfac / ycor - 0.5
    return ((fx, 0.0, cx), (0.0, fy, cy), (0.0, 0.0, 1.0))


# --------------------------------------------------------------------------
# Poses.


def camera_rotation_blender(R):
    """World-to-camera rotation in Blender's camera axes: ``diag(1, -1, -1) @ R``."""
    return matmul(CV_TO_BLENDER_CAMERA, R)


def camera_matrix_local(R, c):
    """The camera object's 4x4 matrix (camera to rig world) from camcal's ``R, c``."""
    Rt = transpose(camera_rotation_blender(R))
    return (
        (Rt[0][0], Rt[0][1], Rt[0][2], float(c[0])),
        (Rt[1][0], Rt[1][1], Rt[1][2], float(c[1])),
        (Rt[2][0], Rt[2][1], Rt[2][2], float(c[2])),
        (0.0, 0.0, 0.0, 1.0),
    )


def rig_matrix(R, c):
    """4x4 rig-to-world matrix from a frame's ``rig_from_world`` pose ``(R, c)``: ``[[R^T, c], [0, 1]]``."""
    Rt = transpose(R)
    return tuple(tuple(Rt[i]) + (float(c[i]),) for i in range(3)) + ((0.0, 0.0, 0.0, 1.0),)


def up_axis_matrix(up_axis="Z"):
    """4x4 matrix taking camcal world coordinates to Blender world coordinates.

    ``up_axis`` names the camcal world axis that should point up (+Z) in
    Blender: ``'Z'`` (identity), ``'Y'`` or ``'-Y'`` (OpenCV-style worlds
    whose y points down).
    """
    if up_axis not in UP_AXES:
        raise ValueError(f"up_axis: unknown {up_axis!r}, expected one of: {', '.join(UP_AXES)}")
    M = UP_AXES[up_axis]
    return tuple(tuple(M[i]) + (0.0,) for i in range(3)) + ((0.0, 0.0, 0.0, 1.0),)


def relative_pose(R1, c1, R2, c2):
    """Pose of camera 2 in camera 1's axes: ``(R_21, t)`` with ``t`` = c2 in cam-1 coordinates."""
    R21 = matmul(R2, transpose(R1))
    d = [c2[i] - c1[i] for i in range(3)]
    t = tuple(sum(R1[i][k] * d[k] for k in range(3)) for i in range(3))
    return R21, t


def is_parallel_pair(cam_a, cam_b, rotation_tol=1e-6, offset_tol=1e-6):
    """Whether two cameras form a rectified (parallel) stereo pair, and the baseline.

    Rectified: same rotation, same ``K`` and image size, and ``b`` sits on
    ``a``'s +x axis (to its right). Returns ``(bool, baseline)``.
    """
    R21, t = relative_pose(cam_a[1], cam_a[2], cam_b[1], cam_b[2])
    rot_err = max(abs(R21[i][j] - (1.0 if i == j else 0.0)) for i in range(3) for j in range(3))
    baseline = math.sqrt(sum(v * v for v in t))
    Ka, Kb = cam_a[0], cam_b[0]
    same_K = all(abs(Ka[i][j] - Kb[i][j]) <= 1e-9 * max(1.0, abs(Ka[i][j])) for i in range(3) for j in range(3))
    ok = (
        rot_err <= rotation_tol
        and same_K
        and baseline > 0
        and t[0] > 0
        and abs(t[1]) <= offset_tol * baseline
        and abs(t[2]) <= offset_tol * baseline
    )
    return ok, baseline


def rectified_camera(K, R, rectification):
    """``(K_rect, R_rect, image_size)`` of the rectified camera.

    The rectifying homography maps original pixels to rectified ones,
    ``x_rect ~ H x``, with both cameras at the same centre, so
    ``H ~ K_rect R_rect R^T K^-1`` and ``R_rect = K_rect^-1 H K R`` up to
    scale; the result is scaled to det +1 and re-orthonormalised.
    """
    M = matmul(matmul(matmul(inverse3(rectification.K_rect), rectification.H), K), R)
    det = _det3(M)
    if det == 0:
        raise ValueError("degenerate rectification homography")
    s = math.copysign(abs(det) ** (1.0 / 3.0), det)
    Rr = tuple(tuple(v / s for v in row) for row in M)
    for _ in range(20):  # Newton's polar iteration: R <- (R + R^-T) / 2
        inv_t = transpose(inverse3(Rr))
        Rr = tuple(tuple(0.5 * (Rr[i][j] + inv_t[i][j]) for j in range(3)) for i in range(3))
    return rectification.K_rect, Rr, tuple(rectification.image_size)


# --------------------------------------------------------------------------
# Distortion.


def to_blender_pixel(point, height):
    """camcal pixel (centres at integers, y down) -> Blender tracking pixel (edges, y up)."""
    return (point[0] + 0.5, height - 0.5 - point[1])


def from_blender_pixel(point, height):
    """Blender tracking pixel (edges, y up) -> camcal pixel (centres at integers, y down)."""
    return (point[0] - 0.5, height - 0.5 - point[1])


def division_undistort(point, center, lam, aspect=1.0):
    """Strand & Hayman: ``x_u = c + (x_d - c) / (1 + lambda r_d^2)`` (pixels; ``r_d^2 = dx^2 + (aspect dy)^2``)."""
    dx, dy = point[0] - center[0], point[1] - center[1]
    f = 1.0 / (1.0 + lam * (dx * dx + aspect * aspect * dy * dy))
    return (center[0] + dx * f, center[1] + dy * f)


def division_distort(point, center, lam, aspect=1.0):
    """Inverse of :func:`division_undistort`: the root of
    ``lambda r_u r_d^2 - r_d + r_u = 0`` that is continuous at ``r_u = 0``
    (radii in x pixels, ``r^2 = dx^2 + (aspect dy)^2``)."""
    dx, dy = point[0] - center[0], point[1] - center[1]
    ru = math.hypot(dx, aspect * dy)
    if ru == 0.0 or lam == 0.0:
        return (float(point[0]), float(point[1]))
    disc = 1.0 - 4.0 * lam * ru * ru
    if disc < 0:
        raise ValueError(f"point at r = {ru:.1f} px is outside the division model's range")
    rd = 2.0 * ru / (1.0 + math.sqrt(disc))
    s = rd / ru
    return (center[0] + dx * s, center[1] + dy * s)


def polynomial_distort(point, center, focal, ks):
    """``r_d = r_u (1 + k1 r_u^2 + k2 r_u^4 + k3 r_u^6)`` in coordinates normalised by ``focal``."""
    x = (point[0] - center[0]) / focal
    y = (point[1] - center[1]) / focal
    r2 = x * x + y * y
    f = 1.0
    p = 1.0
    for k in ks:
        p *= r2
        f += k * p
    return (center[0] + x * f * focal, center[1] + y * f * focal)


def polynomial_undistort(point, center, focal, ks, iterations=50):
    """Inverse of :func:`polynomial_distort` (Newton on the radius)."""
    xd = (point[0] - center[0]) / focal
    yd = (point[1] - center[1]) / focal
    rd = math.hypot(xd, yd)
    if rd == 0.0:
        return (float(point[0]), float(point[1]))
    ru = rd
    for _ in range(iterations):
        r2 = ru * ru
        f, fp, p = 1.0, 1.0, 1.0
        for n, k in enumerate(ks, start=1):
            p *= r2
            f += k * p
            fp += (2 * n + 1) * k * p
        step = (ru * f - rd) / fp
        ru -= step
        if abs(step) < 1e-15:
            break
    s = ru / rd
    return (center[0] + xd * s * focal, center[1] + yd * s * focal)


def opencv_distort(point, center, focal, params):
    """OpenCV's model (k1, k2, p1, p2[, k3][, k4, k5, k6][, s1..s4]) in coordinates
    normalised by one ``focal`` around ``center`` (y down).

    ``radial = (1 + k1 r^2 + k2 r^4 + k3 r^6) / (1 + k4 r^2 + k5 r^4 + k6 r^6)``,
    ``x_d = x radial + 2 p1 x y + p2 (r^2 + 2 x^2) + s1 r^2 + s2 r^4``,
    ``y_d = y radial + p1 (r^2 + 2 y^2) + 2 p2 x y + s3 r^2 + s4 r^4``
    (OpenCV's calib3d documentation)."""
    x = (point[0] - center[0]) / focal
    y = (point[1] - center[1]) / focal
    r2 = x * x + y * y
    k1, k2, k3 = params["k1"], params["k2"], params.get("k3", 0.0)
    k4, k5, k6 = params.get("k4", 0.0), params.get("k5", 0.0), params.get("k6", 0.0)
    p1, p2 = params["p1"], params["p2"]
    radial = (1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1.0 + r2 * (k4 + r2 * (k5 + r2 * k6)))
    xd = x * radial + 2.0 * p1 * x * y + p2 * (r2 + 2.0 * x * x)
    yd = y * radial + p1 * (r2 + 2.0 * y * y) + 2.0 * p2 * x * y
    xd += r2 * (params.get("s1", 0.0) + r2 * params.get("s2", 0.0))
    yd += r2 * (params.get("s3", 0.0) + r2 * params.get("s4", 0.0))
    return (center[0] + xd * focal, center[1] + yd * focal)


def distort(distortion, point, center, focal):
    """Undistorted -> distorted pixel for a :class:`rigfile.Distortion`, around ``center``.

    ``focal`` (pixels) normalises the polynomial and OpenCV models.
    """
    p = distortion.params
    if distortion.model == "division":
        return division_distort(point, center, p["lambda"], p.get("aspect", 1.0))
    if distortion.model == "polynomial":
        return polynomial_distort(point, center, focal, [p.get(k, 0.0) for k in ("k1", "k2", "k3")])
    if distortion.model == "opencv":
        return opencv_distort(point, center, focal, p)
    return (float(point[0]), float(point[1]))


def overscan_margins(image_size, overscan):
    """Whole-pixel margins ``(mx, my)`` on each side for an overscan factor (>= 1)."""
    if not overscan >= 1.0:
        raise ValueError(f"overscan must be >= 1, got {overscan}")
    W, H = image_size
    # The small epsilon keeps e.g. 1.1 * 240 from rounding up a whole pixel.
    return (
        int(math.ceil((overscan - 1.0) * W / 2.0 - 1e-9)),
        int(math.ceil((overscan - 1.0) * H / 2.0 - 1e-9)),
    )


#: The tracking camera's distortion models (``MovieTrackingCamera.distortion_model``).
BLENDER_MODELS = ("POLYNOMIAL", "DIVISION", "NUKE", "BROWN")

#: The Blender model that holds each camcal model exactly (the default target).
EXACT_MODELS = {"none": "POLYNOMIAL", "polynomial": "POLYNOMIAL", "opencv": "BROWN", "division": "NUKE"}

_FIT_TERMS = {"POLYNOMIAL": ("k1", "k2", "k3"), "DIVISION": ("division_k1", "division_k2"),
              "NUKE": ("nuke_k1", "nuke_k2"), "BROWN": ("brown_k1", "brown_k2", "brown_k3", "brown_k4")}


@dataclass(frozen=True)
class BlenderLens:
    """Settings of a MovieClip's tracking camera that carry a camcal lens.

    ``calibration_size`` is the size the clip's frame must have;
    ``principal_point_pixels`` is the *distortion centre* in Blender's
    tracking pixels (bottom-left origin, y up, edges). ``params`` maps
    tracking-camera property names to values. ``fit_max_px`` is 0 when
    Blender's model holds the lens exactly, else the largest distance (pixels)
    between camcal's lens and the fitted one over the frame's radii;
    ``note`` says what is inexact.
    """

    distortion_model: str
    params: dict
    focal_length_pixels: float
    principal_point_pixels: tuple
    calibration_size: tuple
    exact: bool
    note: str
    fit_max_px: float = 0.0


def _blender_radial(model, params, rho2):
    """The radial factor ``r_d / r_u`` of POLYNOMIAL and BROWN, ``r_u / r_d`` of DIVISION (normalised ``rho2``)."""
    if model == "DIVISION":
        return 1.0 / (1.0 + rho2 * (params["division_k1"] + rho2 * params["division_k2"]))
    ks = [params[k] for k in _FIT_TERMS[model]]
    factor, power = 1.0, 1.0
    for k in ks:
        power *= rho2
        factor += k * power
    return factor


def _nuke_half(size):
    return max(size) / 2.0


def _nuke_undistort_radius(params, r_d, half):
    rho2 = (r_d / half) ** 2
    return r_d / (1.0 + rho2 * (params["nuke_k1"] + rho2 * params["nuke_k2"]))


def _nuke_distort_radius(params, r_u, half):
    """Newton on ``r_u = r_d / (1 + k1 rho_d^2 + k2 rho_d^4)`` for ``r_d``, started at ``r_u``."""
    r_d = r_u
    for _ in range(60):
        rho2 = (r_d / half) ** 2
        denominator = 1.0 + rho2 * (params["nuke_k1"] + rho2 * params["nuke_k2"])
        slope = (denominator - rho2 * (2.0 * params["nuke_k1"] + 4.0 * params["nuke_k2"] * rho2)) / denominator ** 2
        step = (r_d / denominator - r_u) / slope
        r_d -= step
        if abs(step) < 1e-13 * max(1.0, r_u):
            break
    return r_d


def blender_distort(lens, point):
    """Where Blender's tracking camera ``lens`` puts an undistorted pixel.

    ``point`` and the result are camcal pixels (centres at integers, y down)
    of the lens's calibration frame. The formulas are libmv's (Blender's
    tracking library, ``distortion_models.h``), in Blender's tracking pixels
    (edges, y up) around the principal point ``c``, normalised by the focal
    length ``f`` (``rho = (x - c) / f``):

    - POLYNOMIAL: ``rho_d = rho_u (1 + k1 r^2 + k2 r^4 + k3 r^6)``, ``r = |rho_u|``;
    - BROWN: the same with ``k4 r^8``, plus ``p1 (r^2 + 2 x^2) + 2 p2 x y``
      on x and ``p2 (r^2 + 2 y^2) + 2 p1 x y`` on y (OpenCV's with p1 and
      p2 exchanged);
    - DIVISION: ``rho_d = rho_u / (1 + k1 r^2 + k2 r^4)``, ``r = |rho_u|``
      (the *undistorted* radius, unlike Fitzgibbon's division model);
    - NUKE: ``x_u = x_d / (1 + k1 r^2 + k2 r^4)`` with ``r = |x_d - c| /
      (max(W, H) / 2)`` (Nuke's classic model, distorted -> undistorted;
      inverted here by Newton's method).

    The formulas were checked against Blender's own Movie Distortion node
    (tests/addon/test_addon_blender_lens.py).
    """
    Hc = lens.calibration_size[1]
    cx, cy = lens.principal_point_pixels
    bx, by = to_blender_pixel(point, Hc)
    dx, dy = bx - cx, by - cy
    p = lens.params
    if lens.distortion_model == "NUKE":
        r_u = math.hypot(dx, dy)
        if r_u == 0.0:
            return (float(point[0]), float(point[1]))
        scale = _nuke_distort_radius(p, r_u, _nuke_half(lens.calibration_size)) / r_u
        return from_blender_pixel((cx + dx * scale, cy + dy * scale), Hc)
    f = lens.focal_length_pixels
    x, y = dx / f, dy / f
    r2 = x * x + y * y
    radial = _blender_radial(lens.distortion_model, p, r2)
    xd, yd = x * radial, y * radial
    if lens.distortion_model == "BROWN":
        p1, p2 = p["brown_p1"], p["brown_p2"]
        xd += p1 * (r2 + 2.0 * x * x) + 2.0 * p2 * x * y
        yd += p2 * (r2 + 2.0 * y * y) + 2.0 * p1 * x * y
    return from_blender_pixel((cx + xd * f, cy + yd * f), Hc)


def _fit_radial(distortion, model, focal, half, r_max, n_samples=200):
    """Fit Blender ``model``'s radial terms to camcal's radial lens over radii up to ``r_max`` pixels.

    Linear least squares in the form each model is linear in (POLYNOMIAL and
    BROWN: ``r_d / r_u - 1``; DIVISION: ``r_u / r_d - 1``, both in powers of
    ``rho_u^2``; NUKE: ``r_d / r_u - 1`` in powers of ``rho_d^2`` with
    ``rho = r / half``), each sample weighted by the pixels a unit residual
    moves the distorted point; then Gauss-Newton steps on the distorted
    radius itself. Returns ``(params, max_px)``.
    """
    names = _FIT_TERMS[model]
    samples = []
    for i in range(1, n_samples + 1):
        r_d = r_max * i / n_samples
        r_u = _inverse_radius(distortion, r_d, focal)
        samples.append((r_u, r_d))

    def predicted(params, r_u):
        if model == "NUKE":
            return _nuke_distort_radius(params, r_u, half)
        return r_u * _blender_radial(model, params, (r_u / focal) ** 2)

    rows, targets, weights = [], [], []
    for r_u, r_d in samples:
        if model == "NUKE":
            rho2 = (r_d / half) ** 2
            rows.append([rho2 ** (n + 1) for n in range(len(names))])
            targets.append(r_d / r_u - 1.0)
            weights.append(r_u)
        elif model == "DIVISION":
            rho2 = (r_u / focal) ** 2
            rows.append([rho2 ** (n + 1) for n in range(len(names))])
            targets.append(r_u / r_d - 1.0)
            weights.append(r_d * r_d / r_u)
        else:
            rho2 = (r_u / focal) ** 2
            rows.append([rho2 ** (n + 1) for n in range(len(names))])
            targets.append(r_d / r_u - 1.0)
            weights.append(r_u)
    coefficients = _weighted_least_squares(rows, targets, weights)
    for _ in range(10):  # Gauss-Newton on the distorted radius (numeric Jacobian)
        params = dict(zip(names, coefficients))
        residuals = [predicted(params, r_u) - r_d for r_u, r_d in samples]
        jacobian = []
        for r_u, _r_d in samples:
            row = []
            for n, name in enumerate(names):
                step = 1e-7 * max(1.0, abs(coefficients[n]))
                bumped = dict(params, **{name: coefficients[n] + step})
                row.append((predicted(bumped, r_u) - predicted(params, r_u)) / step)
            jacobian.append(row)
        delta = _weighted_least_squares(jacobian, [-e for e in residuals], [1.0] * len(residuals))
        coefficients = [c + d for c, d in zip(coefficients, delta)]
    params = dict(zip(names, coefficients))
    worst = max(abs(predicted(params, r_u) - r_d) for r_u, r_d in samples)
    return params, worst


def _inverse_radius(distortion, r_d, focal):
    """The undistorted radius (pixels) whose camcal distorted radius is ``r_d``, for a radial lens (along +x)."""
    if distortion.model == "division":
        return division_undistort((r_d, 0.0), (0.0, 0.0), distortion.params["lambda"])[0]
    if distortion.model == "polynomial":
        ks = [distortion.params.get(k, 0.0) for k in ("k1", "k2", "k3")]
        return polynomial_undistort((r_d, 0.0), (0.0, 0.0), focal, ks)[0]
    if distortion.model == "none":
        return r_d
    raise ValueError(f"{distortion.model!r} is not a radial lens this mapping refits")


def _weighted_least_squares(rows, targets, weights):
    n = len(rows[0])
    A = [[sum(w * w * row[i] * row[j] for row, w in zip(rows, weights)) for j in range(n)] for i in range(n)]
    b = [sum(w * w * row[i] * t for row, t, w in zip(rows, targets, weights)) for i in range(n)]
    return solve_linear(A, b)


def solve_linear(A, b):
    """Solve the small dense system ``A x = b`` (Gaussian elimination, partial pivoting); ValueError if singular."""
    n = len(b)
    M = [list(A[i]) + [b[i]] for i in range(n)]
    for col in range(n):
        pivot = max(range(col, n), key=lambda r: abs(M[r][col]))
        M[col], M[pivot] = M[pivot], M[col]
        if M[col][col] == 0.0:
            raise ValueError("singular fit")
        for r in range(col + 1, n):
            f = M[r][col] / M[col][col]
            for c in range(col, n + 1):
                M[r][c] -= f * M[col][c]
    x = [0.0] * n
    for r in range(n - 1, -1, -1):
        x[r] = (M[r][n] - sum(M[r][c] * x[c] for c in range(r + 1, n))) / M[r][r]
    return x


def _exact_params(model, target, p, size):
    """Blender's parameters holding camcal's lens exactly, or None when ``target`` cannot."""
    if model == "none":
        tangential = {"brown_p1": 0.0, "brown_p2": 0.0} if target == "BROWN" else {}
        return dict.fromkeys(_FIT_TERMS[target], 0.0) | tangential
    if model == "division" and target == "NUKE":
        half = _nuke_half(size)
        return {"nuke_k1": p["lambda"] * half * half, "nuke_k2": 0.0}
    if model == "polynomial" and target == "POLYNOMIAL":
        return {"k1": p.get("k1", 0.0), "k2": p.get("k2", 0.0), "k3": p.get("k3", 0.0)}
    if model in ("polynomial", "opencv") and target == "BROWN":
        return {
            "brown_k1": p["k1"], "brown_k2": p["k2"], "brown_k3": p.get("k3", 0.0), "brown_k4": 0.0,
            # libmv's Brown model swaps OpenCV's p1 and p2, and Blender's y axis points up.
            "brown_p1": p.get("p2", 0.0), "brown_p2": -p.get("p1", 0.0),
        }
    if model == "opencv" and target == "POLYNOMIAL" and not (p["p1"] or p["p2"]):
        return {"k1": p["k1"], "k2": p["k2"], "k3": p.get("k3", 0.0)}
    return None


def _frame_radius(center, size):
    """Largest distance (pixels) from ``center`` to a corner of the frame (pixel edges)."""
    W, H = size
    return max(math.hypot(x - center[0], y - center[1]) for x in (-0.5, W - 0.5) for y in (-0.5, H - 0.5))


def blender_lens(distortion, K, image_size, margins=(0, 0), model=None):
    """The tracking-camera lens for a camcal distortion model.

    Parameters
    ----------
    distortion : rigfile.Distortion
    K : 3x3
        Gives the focal length (pixels) used for normalised models.
    image_size : (W, H)
    margins : (mx, my)
        Overscan margins added on each side: the frame is then
        ``(W + 2 mx, H + 2 my)`` and the centre moves by the margins.
    model : {None, 'POLYNOMIAL', 'DIVISION', 'NUKE', 'BROWN'}
        Blender's model to use; None picks the one that holds the lens
        exactly (:data:`EXACT_MODELS`).

    Returns
    -------
    BlenderLens

    Notes
    -----
    Exact pairs (:func:`blender_distort` has Blender's formulas):
    ``polynomial`` -> POLYNOMIAL (or BROWN with ``k4 = 0``); ``opencv``
    (``k1, k2, p1, p2, k3``) -> BROWN with ``brown_p1 = p2``,
    ``brown_p2 = -p1`` (libmv exchanges OpenCV's tangential terms, and
    Blender's y axis points up), ``brown_k4 = 0`` (libmv's ``k4`` is an
    ``r^8`` term, not OpenCV's rational one); ``division`` -> NUKE with
    ``nuke_k1 = lambda (max(W, H) / 2)^2`` on the calibration frame
    (Strand & Hayman's model is Nuke's classic one with ``k2 = 0``).
    Blender normalises both axes by one focal length without skew, so the
    polynomial models are exact only with ``fx == fy`` and no skew; BROWN
    has no rational (``k4..k6``) or thin-prism (``s1..s4``) terms; NUKE's
    radius is round in pixels (the division model's ``aspect`` must be 1).
    Any other pair is a fit of Blender's radial terms to camcal's radial
    lens (``division`` with aspect 1, ``polynomial``) over the radii from
    the centre to the frame's farthest corner, reported in ``fit_max_px``.
    """
    W, H = image_size
    mx, my = margins
    Wc, Hc = W + 2 * mx, H + 2 * my
    center = distortion.center if distortion.center is not None else (K[0][2], K[1][2])
    pp = to_blender_pixel((center[0] + mx, center[1] + my), Hc)
    fx, fy = float(K[0][0]), float(K[1][1])
    source = distortion.model
    p = distortion.params
    if source not in EXACT_MODELS:  # rigfile validates models; the fisheyes go to Cycles' camera instead
        raise ValueError(f"no Blender tracking model for the {source!r} lens (use the ST-maps)")
    target = EXACT_MODELS[source] if model is None else model
    if target not in BLENDER_MODELS:
        raise ValueError(f"unknown Blender distortion model {target!r}, expected one of: {', '.join(BLENDER_MODELS)}")
    notes, fit_max = [], 0.0
    params = _exact_params(source, target, p, (Wc, Hc))
    if params is None:
        if source == "opencv":
            raise ValueError(f"Blender's {target} model has no tangential terms: the opencv lens goes to BROWN")
        if p.get("aspect", 1.0) != 1.0:
            raise ValueError(f"the division lens's aspect {p['aspect']:.6g} is not round: "
                             "Blender's models are (use the ST-maps)")
        fitted, fit_max = _fit_radial(distortion, target, fx, _nuke_half((Wc, Hc)), _frame_radius(center, (W, H)))
        params = fitted | ({"brown_p1": 0.0, "brown_p2": 0.0} if target == "BROWN" else {})
        notes.append(f"Blender's {target} model fitted to the {source} lens: {fit_max:.3g} px at worst over the frame")
    if source == "division" and p.get("aspect", 1.0) != 1.0:
        # camcal's radius is in x pixels with y scaled by the aspect; Blender's NUKE radius is in pixels
        notes.append(f"Blender's NUKE model is round in pixels; this lens's radius scales y by its "
                     f"aspect {p['aspect']:.6g} (use the ST-maps)")
    extra = [name for name in ("k4", "k5", "k6", "s1", "s2", "s3", "s4") if p.get(name, 0.0)]
    if source == "opencv" and extra:
        notes.append(f"Blender's BROWN model has no {', '.join(extra)}: they are left out (use the ST-maps)")
    elif source in ("polynomial", "opencv") and (abs(fx - fy) > 1e-9 * fx or K[0][1] != 0):
        # camcal normalises with K^-1 (fx, fy and skew); Blender with fx alone.
        notes.append("Blender normalises both axes by one focal length (fx), without skew")
    exact = not notes
    return BlenderLens(
        distortion_model=target,
        params=params,
        focal_length_pixels=fx,
        principal_point_pixels=pp,
        calibration_size=(Wc, Hc),
        exact=exact,
        note="; ".join(notes),
        fit_max_px=fit_max,
    )
