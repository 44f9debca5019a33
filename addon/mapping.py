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
*edges* (the tracking camera from the bottom-left corner, y up). The lens
(the MovieClip's tracking camera) is :mod:`.tracking`'s.

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
    "blender_intrinsics",
    "intrinsics_from_blender",
    "camera_rotation_blender",
    "camera_matrix_local",
    "up_axis_matrix",
    "rig_matrix",
    "rectified_camera",
    "relative_pose",
    "is_parallel_pair",
    "matmul",
    "transpose",
    "inverse3",
    "solve_linear",
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
