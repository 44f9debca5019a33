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
    "blender_lens",
    "BlenderFisheye",
    "blender_fisheye",
    "fisheye_polynomial_ray",
    "kannala_brandt_theta_d",
    "kannala_brandt_theta",
    "fisheye_radial_terms",
    "thin_prism_offset_px",
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


@dataclass(frozen=True)
class BlenderLens:
    """Settings of a MovieClip's tracking camera that carry a camcal lens.

    ``calibration_size`` is the size the clip's frame must have;
    ``principal_point_pixels`` is the *distortion centre* in Blender's
    tracking pixels (bottom-left origin, y up, edges). ``params`` maps
    tracking-camera property names to values.
    """

    distortion_model: str
    params: dict
    focal_length_pixels: float
    principal_point_pixels: tuple
    calibration_size: tuple
    exact: bool
    note: str


def blender_lens(distortion, K, image_size, margins=(0, 0)):
    """The tracking-camera lens for a camcal distortion model.

    Parameters
    ----------
    distortion : rigfile.Distortion
        ``division`` becomes Blender's ``NUKE`` model (Strand & Hayman
        distorted -> undistorted, radius normalised by ``max(W, H) / 2``):
        ``nuke_k1 = lambda * (max(W, H) / 2) ** 2``; ``polynomial`` becomes
        ``POLYNOMIAL`` (radius normalised by the focal length ``fx``).
        ``opencv`` becomes ``BROWN`` with ``brown_p1 = p2`` and
        ``brown_p2 = -p1`` (libmv swaps OpenCV's tangential terms, and
        Blender's y axis points up); exact only with fx == fy and
        without OpenCV's rational (k4..k6) and thin-prism (s1..s4) terms,
        which BROWN lacks (left out, said in ``note``).
    K : 3x3
        Gives the focal length (pixels) used for normalised models.
    image_size : (W, H)
    margins : (mx, my)
        Overscan margins added on each side: the frame is then
        ``(W + 2 mx, H + 2 my)`` and the centre moves by the margins.

    Returns
    -------
    BlenderLens
    """
    W, H = image_size
    mx, my = margins
    Wc, Hc = W + 2 * mx, H + 2 * my
    center = distortion.center if distortion.center is not None else (K[0][2], K[1][2])
    pp = to_blender_pixel((center[0] + mx, center[1] + my), Hc)
    fx, fy = float(K[0][0]), float(K[1][1])
    model = distortion.model
    p = distortion.params
    exact = True
    note = ""
    if model == "none":
        blender_model, params = "POLYNOMIAL", {"k1": 0.0, "k2": 0.0, "k3": 0.0}
    elif model == "division":
        half = max(Wc, Hc) / 2.0
        blender_model, params = "NUKE", {"nuke_k1": p["lambda"] * half * half, "nuke_k2": 0.0}
        if p.get("aspect", 1.0) != 1.0:
            # camcal's radius is in x pixels with y scaled by the aspect; Blender's NUKE radius is in pixels
            exact, note = False, (f"Blender's NUKE model is round in pixels; this lens's radius scales y by its "
                                  f"aspect {p['aspect']:.6g} (use the ST-maps)")
    elif model == "polynomial":
        blender_model = "POLYNOMIAL"
        params = {"k1": p.get("k1", 0.0), "k2": p.get("k2", 0.0), "k3": p.get("k3", 0.0)}
    elif model == "opencv":
        blender_model = "BROWN"
        params = {
            "brown_k1": p["k1"], "brown_k2": p["k2"], "brown_k3": p.get("k3", 0.0), "brown_k4": 0.0,
            # libmv's Brown model swaps OpenCV's p1 and p2, and Blender's y axis points up.
            "brown_p1": p["p2"], "brown_p2": -p["p1"],
        }
    else:  # rigfile validates models; keep the error explicit anyway
        raise ValueError(f"unknown distortion model {model!r}")
    extra = [name for name in ("k4", "k5", "k6", "s1", "s2", "s3", "s4") if p.get(name, 0.0)]
    if model == "opencv" and extra:
        # Blender's BROWN model is k1..k4 polynomial + p1, p2: no rational denominator, no thin prism
        exact, note = False, f"Blender's BROWN model has no {', '.join(extra)}: they are left out (use the ST-maps)"
    elif model in ("polynomial", "opencv") and (abs(fx - fy) > 1e-9 * fx or K[0][1] != 0):
        # camcal normalises with K^-1 (fx, fy and skew); Blender with fx alone.
        exact, note = False, "Blender normalises both axes by one focal length (fx), without skew"
    return BlenderLens(
        distortion_model=blender_model,
        params=params,
        focal_length_pixels=fx,
        principal_point_pixels=pp,
        calibration_size=(Wc, Hc),
        exact=exact,
        note=note,
    )


# --------------------------------------------------------------------------
# Fisheye: camcal's Kannala-Brandt lens as Cycles' fisheye-polynomial camera.


def kannala_brandt_theta_d(theta, ks):
    """Kannala & Brandt (2006), OpenCV's fisheye model:
    ``theta_d = theta (1 + k1 theta^2 + k2 theta^4 + k3 theta^6 + k4 theta^8)``
    (``ks`` of any length: six for the thin-prism fisheye's radial part)."""
    t2 = theta * theta
    series = 0.0
    for k in reversed(ks):
        series = t2 * (k + series)
    return theta * (1.0 + series)


def _kannala_brandt_slope(theta, ks):
    t2 = theta * theta
    series = 0.0
    for n in reversed(range(len(ks))):
        series = t2 * ((2 * n + 3) * ks[n] + series)
    return 1.0 + series


def fisheye_radial_terms(params):
    """``k1..k4`` of a ``kannala-brandt`` lens, ``k1..k6`` of a ``kannala-brandt-thin-prism`` one."""
    return [float(params[k]) for k in ("k1", "k2", "k3", "k4", "k5", "k6") if k in params]


def thin_prism_offset_px(K, image_size, params, step=16):
    """Largest shift (pixels) the tangential and thin-prism terms of a ``kannala-brandt-thin-prism``
    lens make over the frame: what Cycles' radial fisheye camera leaves out.

    The terms act on the fisheye point ``(x, y)`` (normalised): ``dx = 2 p1 x y + p2 (r^2 + 2 x^2)
    + s1 r^2 + s2 r^4``, ``dy = p1 (r^2 + 2 y^2) + 2 p2 x y + s3 r^2 + s4 r^4``; evaluated at the
    frame's pixels (to first order in the shift)."""
    fx, fy, cx, cy = float(K[0][0]), float(K[1][1]), float(K[0][2]), float(K[1][2])
    p1, p2 = params.get("p1", 0.0), params.get("p2", 0.0)
    s1, s2, s3, s4 = (params.get(k, 0.0) for k in ("s1", "s2", "s3", "s4"))
    worst = 0.0
    for u in range(0, int(image_size[0]), step):
        for v in range(0, int(image_size[1]), step):
            x, y = (u - cx) / fx, (v - cy) / fy
            r2 = x * x + y * y
            dx = 2 * p1 * x * y + p2 * (r2 + 2 * x * x) + r2 * (s1 + r2 * s2)
            dy = p1 * (r2 + 2 * y * y) + 2 * p2 * x * y + r2 * (s3 + r2 * s4)
            worst = max(worst, math.hypot(dx * fx, dy * fy))
    return worst


def _kannala_brandt_max_angle(ks):
    """First angle (at most pi) where ``d theta_d / d theta`` reaches 0: the model is one-to-one below it."""
    step = math.pi / 2048
    theta = 0.0
    while theta < math.pi:
        if _kannala_brandt_slope(theta + step, ks) <= 0.0:
            low, high = theta, theta + step
            for _ in range(60):
                middle = 0.5 * (low + high)
                low, high = (middle, high) if _kannala_brandt_slope(middle, ks) > 0.0 else (low, middle)
            return low
        theta += step
    return math.pi


def kannala_brandt_theta(theta_d, ks, theta_max=None):
    """Inverse of :func:`kannala_brandt_theta_d` on ``[0, theta_max]`` (bisection-safeguarded Newton)."""
    theta_max = _kannala_brandt_max_angle(ks) if theta_max is None else theta_max
    if not 0.0 <= theta_d <= kannala_brandt_theta_d(theta_max, ks):
        raise ValueError(f"theta_d {theta_d:.6g} is beyond the lens model's range")
    low, high, theta = 0.0, theta_max, min(theta_d, theta_max)
    for _ in range(100):
        residual = kannala_brandt_theta_d(theta, ks) - theta_d
        if residual < 0.0:
            low = theta
        elif residual > 0.0:
            high = theta
        else:
            return theta
        step = theta - residual / _kannala_brandt_slope(theta, ks)
        new = step if low < step < high else 0.5 * (low + high)
        if abs(new - theta) <= 1e-15 * max(1.0, theta):
            return new
        theta = new
    return theta


def _solve(A, b):
    """Gaussian elimination with partial pivoting for a small dense system."""
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


@dataclass(frozen=True)
class BlenderFisheye:
    """Blender camera settings for a camcal ``kannala-brandt`` lens.

    A panoramic camera, ``panorama_type = 'FISHEYE_LENS_POLYNOMIAL'``:
    Cycles maps a pixel at ``r`` mm from the sensor centre to the ray at
    ``theta = -(k0 + k1 r + k2 r^2 + k3 r^3 + k4 r^4)`` from the axis.
    ``polynomial`` is ``(k0, k1, k2, k3, k4)`` (``k0 = 0``), fitted to
    camcal's model over the frame; ``fit_rms_px`` / ``fit_max_px`` are the
    residuals of that fit in pixels over the radii of the frame (up to its
    farthest corner); ``max_angle`` (radians) is the widest ray the frame
    holds, ``fov`` what Cycles clips at (``2 max_angle``).
    """

    resolution_x: int
    resolution_y: int
    pixel_aspect_x: float
    pixel_aspect_y: float
    sensor_fit: str
    sensor_width: float
    sensor_height: float
    shift_x: float
    shift_y: float
    fov: float
    polynomial: tuple
    fit_rms_px: float
    fit_max_px: float
    max_angle: float


def _pixel_pitch_mm(b):
    """Millimetres per pixel across x and y on Cycles' panoramic sensor for settings ``b``
    (:class:`BlenderIntrinsics` or :class:`BlenderFisheye`).

    Cycles (blender/camera.cpp) sizes the fisheye sensor by the fit: with
    ``fx_ratio = W ax``, ``fy_ratio = H ay``, a horizontal fit (AUTO when
    ``fx_ratio > fy_ratio``) spans ``S`` mm over the width, a vertical one
    over the height, ``S`` the sensor width (AUTO, HORIZONTAL) or height
    (VERTICAL); so ``pitch_y / pitch_x = ay / ax``.
    """
    W, H = b.resolution_x, b.resolution_y
    ax, ay = b.pixel_aspect_x, b.pixel_aspect_y
    if b.sensor_fit == "AUTO":
        horizontal, size = W * ax > H * ay, b.sensor_width
    elif b.sensor_fit == "HORIZONTAL":
        horizontal, size = True, b.sensor_width
    else:
        horizontal, size = False, b.sensor_height
    pitch_x = size / W if horizontal else size * ax / (H * ay)
    return pitch_x, pitch_x * ay / ax


def blender_fisheye(K, image_size, params, sensor_width_mm=36.0, sensor_fit="AUTO", n_samples=400):
    """Cycles fisheye-polynomial settings that project like camcal's ``kannala-brandt`` lens.

    Parameters
    ----------
    K : 3x3 nested sequence
        ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` in pixels, pixel centres at
        integers (camcal's convention); ``fx != fy`` goes to the pixel aspect.
    image_size : (int, int)
    params : mapping
        ``k1, k2, k3, k4`` of camcal's model (OpenCV's fisheye model); with
        ``k5, k6`` (``kannala-brandt-thin-prism``) its six radial terms; the
        tangential and thin-prism terms are not Cycles': they are left out
        (:func:`thin_prism_offset_px` says by how much).
    sensor_width_mm : float
    sensor_fit : {'AUTO', 'HORIZONTAL', 'VERTICAL'}
    n_samples : int
        Radii sampled for the fit, from the centre to the frame's farthest corner.

    Returns
    -------
    BlenderFisheye

    Notes
    -----
    camcal puts the ray at angle ``theta`` at normalised radius
    ``theta_d(theta)``, i.e. ``g theta_d`` mm from the principal point with
    ``g = fx pitch_x = fy pitch_y`` mm per normalised unit. Cycles needs
    the inverse, ``theta(r)``, as a quartic in ``r`` without constant term:
    ``k1..k4`` minimise the largest ``|P(r_i) - theta(r_i)| w_i`` with
    ``w = g theta_d'(theta) / pitch_x`` (pixels per radian), i.e. the error in
    pixels, over radii from the centre to the farthest frame corner
    (Lawson's iteratively reweighted least squares on radii scaled to
    [0, 1]). A quartic holds the inverse of camcal's ninth-degree odd
    polynomial only approximately: ``fit_max_px`` says how well. The
    principal point goes to the shifts in fractions of the frame (Cycles'
    panoramic viewplane is [0, 1] on each axis):
    ``shift_x = (W / 2 - (cx + 0.5)) / W``, ``shift_y = ((cy + 0.5) - H / 2) / H``.
    """
    W, H = int(image_size[0]), int(image_size[1])
    if abs(float(K[0][1])) > 1e-9 * float(K[0][0]):
        raise ValueError("skew cannot be represented by Blender's fisheye camera")
    b = blender_intrinsics(K, image_size, sensor_width_mm, sensor_fit)
    fx, cx, cy = float(K[0][0]), float(K[0][2]), float(K[1][2])
    ks = fisheye_radial_terms(params)
    pitch_x, pitch_y = _pixel_pitch_mm(b)
    g = fx * pitch_x
    theta_limit = _kannala_brandt_max_angle(ks)
    # farthest frame corner (pixel edges) in normalised radius
    fy = float(K[1][1])
    corners = [((x - cx) / fx, (y - cy) / fy) for x in (-0.5, W - 0.5) for y in (-0.5, H - 0.5)]
    theta_d_max = min(max(math.hypot(*c) for c in corners), kannala_brandt_theta_d(theta_limit, ks))
    r_max = g * theta_d_max
    samples = []
    for i in range(1, n_samples + 1):
        theta_d = theta_d_max * i / n_samples
        theta = kannala_brandt_theta(theta_d, ks, theta_limit)
        weight = g * _kannala_brandt_slope(theta, ks) / pitch_x
        samples.append((theta_d * g / r_max, theta, weight))

    def pixel_errors(c):
        return [abs(sum(c[n] * s ** (n + 1) for n in range(4)) - theta) * w for s, theta, w in samples]

    # Lawson's iteration: weighted least squares whose weights grow where the error is large tends
    # to the minimax (smallest largest error) fit; keep the best iterate.
    lawson = [1.0] * len(samples)
    best = None
    for _ in range(40):
        A = [[0.0] * 4 for _ in range(4)]
        rhs = [0.0] * 4
        for (s, theta, w), extra in zip(samples, lawson):
            row = [s ** (n + 1) for n in range(4)]
            weight = w * w * extra
            for i in range(4):
                rhs[i] += weight * row[i] * theta
                for j in range(4):
                    A[i][j] += weight * row[i] * row[j]
        c = _solve(A, rhs)
        errors = pixel_errors(c)
        if best is None or max(errors) < max(best[1]):
            best = (c, errors)
        total = sum(e * x for e, x in zip(errors, lawson))
        if total == 0.0:
            break
        lawson = [x * e / total for x, e in zip(lawson, errors)]
    c, errors = best
    coefficients = tuple(-c[n] / r_max ** (n + 1) for n in range(4))
    max_angle = kannala_brandt_theta(theta_d_max, ks, theta_limit)
    return BlenderFisheye(
        resolution_x=W,
        resolution_y=H,
        pixel_aspect_x=b.pixel_aspect_x,
        pixel_aspect_y=b.pixel_aspect_y,
        sensor_fit=sensor_fit,
        sensor_width=b.sensor_width,
        sensor_height=b.sensor_height,
        shift_x=(W / 2.0 - (cx + 0.5)) / W,
        shift_y=((cy + 0.5) - H / 2.0) / H,
        fov=2.0 * max_angle,
        polynomial=(0.0,) + coefficients,
        fit_rms_px=math.sqrt(sum(e * e for e in errors) / len(errors)),
        fit_max_px=max(errors),
        max_angle=max_angle,
    )


def fisheye_polynomial_ray(f, pixel):
    """The ray Cycles traces through ``pixel`` for :class:`BlenderFisheye` settings ``f``.

    Cycles' formula (kernel/camera/projection.h,
    ``fisheye_lens_polynomial_to_direction``) in camcal's axes: pixel
    centres at integers, camera +x right, +y down, +z forward. Returns a
    unit 3-tuple, or ``None`` beyond ``fov / 2`` (Cycles renders black).
    """
    W, H = f.resolution_x, f.resolution_y
    pitch_x, pitch_y = _pixel_pitch_mm(f)
    u = (pixel[0] - (W / 2.0 - f.shift_x * W - 0.5)) * pitch_x
    v = (pixel[1] - (H / 2.0 + f.shift_y * H - 0.5)) * pitch_y
    r = math.hypot(u, v)
    k = f.polynomial
    theta = -(k[0] + r * (k[1] + r * (k[2] + r * (k[3] + r * k[4]))))
    if abs(theta) > 0.5 * f.fov:
        return None
    if r == 0.0:
        return (0.0, 0.0, 1.0)
    s = math.sin(theta) / r
    return (u * s, v * s, math.cos(theta))
