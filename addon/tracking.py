"""camcal lenses -> the MovieClip tracking camera's lens, in plain Python.

No bpy, no numpy: the lens maths runs and is tested outside Blender.
camcal's distortion models (pixel (0, 0) at the centre of the top-left
pixel, y down) and Blender's four tracking models (libmv's formulas, in
Blender's tracking pixels: edges, bottom-left origin, y up), the choice of
Blender model for each camcal lens, and the fit where none holds it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .mapping import solve_linear

__all__ = [
    "BLENDER_MODELS",
    "ROUND_ASPECT",
    "EXACT_MODELS",
    "BlenderLens",
    "blender_lens",
    "blender_distort",
    "overscan_margins",
    "division_distort",
    "division_undistort",
    "polynomial_distort",
    "polynomial_undistort",
    "opencv_distort",
    "distort",
    "to_blender_pixel",
    "from_blender_pixel",
]

#: A division lens whose aspect is this close to 1 is round (a solve that held square pixels writes 1 + 1e-11).
ROUND_ASPECT = 1e-9


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
        if abs(p.get("aspect", 1.0) - 1.0) > ROUND_ASPECT:
            raise ValueError(f"the division lens's aspect {p['aspect']:.6g} is not round: "
                             "Blender's models are (use the ST-maps)")
        fitted, fit_max = _fit_radial(distortion, target, fx, _nuke_half((Wc, Hc)), _frame_radius(center, (W, H)))
        params = fitted | ({"brown_p1": 0.0, "brown_p2": 0.0} if target == "BROWN" else {})
        notes.append(f"Blender's {target} model fitted to the {source} lens: {fit_max:.3g} px at worst over the frame")
    if source == "division" and abs(p.get("aspect", 1.0) - 1.0) > ROUND_ASPECT:
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
