"""camcal's Kannala-Brandt lens as Cycles' fisheye-polynomial camera, in plain Python.

No bpy, no numpy (like :mod:`.mapping`, whose intrinsics it builds on).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .mapping import blender_intrinsics, solve_linear

__all__ = [
    "BlenderFisheye",
    "blender_fisheye",
    "fisheye_polynomial_ray",
    "kannala_brandt_theta_d",
    "kannala_brandt_theta",
    "fisheye_radial_terms",
    "thin_prism_offset_px",
]


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
        c = solve_linear(A, rhs)
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
