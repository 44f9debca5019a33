"""The four 3DE models' documented formulas, written here from the LDPK documentation (Science-D-Visions, Lens
Distortion Plugin Kit 2.0, model documentation of ``tde4_ldp_classic_3de_mixed``,
``tde4_ldp_radial_decentered_deg_4_cylindric``, ``tde4_ldp_anamorphic_deg_4_rotate_squeeze_xy`` and
``tde4_ldp_radial_deg_8``; Sassenberg 2018, "The Standard Models for Lens Distortion in 3DE4"), independently of
camcal's model code: the tests evaluate what a Nuke or 3DE node holds with them.

All in diagonally normalised coordinates (lens centre at 0, film back half-diagonal 1, y up), distorted ->
undistorted (LDPK's ``undistort``), which is what the coefficients mean.
"""

import numpy as np


def _classic(p, c):
    x, y = p[:, 0], p[:, 1]
    ld, sq, cx, cy, qu = c["distortion"], c["anamorphic_squeeze"], c["curvature_x"], c["curvature_y"], \
        c["quartic_distortion"]
    r4 = (x * x + y * y) ** 2
    return np.column_stack([x * (1 + ld / sq * x * x + (ld + cx) / sq * y * y + qu / sq * r4),
                            y * (1 + (ld + cy) * x * x + ld * y * y + qu * r4)])


def _radial(p, c):
    x, y = p[:, 0], p[:, 1]
    r2 = x * x + y * y
    radial = 1 + c["c2"] * r2 + c["c4"] * r2 * r2
    u, v = c["u2"] + c["u4"] * r2, c["v2"] + c["v4"] * r2
    s = np.column_stack([x * radial + (r2 + 2 * x * x) * u + 2 * x * y * v,
                         y * radial + (r2 + 2 * y * y) * v + 2 * x * y * u])
    phi, k = np.radians(c["cylindric_direction_deg"]), np.sqrt(1 + c["cylindric_bending"])
    cs, sn = np.cos(phi), np.sin(phi)
    C = np.array([[cs * cs * k + sn * sn / k, (k - 1 / k) * cs * sn], [(k - 1 / k) * cs * sn, cs * cs / k + sn * sn * k]])
    return s @ C.T


def _anamorphic(p, c, pixel_aspect):
    phi = np.radians(c["lens_rotation_deg"])
    rot = np.array([[np.cos(phi), -np.sin(phi)], [np.sin(phi), np.cos(phi)]])
    P = np.diag([pixel_aspect, 1.0])
    inner = p @ np.linalg.inv(P @ rot).T
    x, y = inner[:, 0], inner[:, 1]
    x2, y2 = x * x, y * y

    def polar(a):  # sum a_ij cos(i phi) r^j, written out in x, y
        a02, a22, a04, a24, a44 = a
        return (1 + (a02 + a22) * x2 + (a02 - a22) * y2 + (a04 + a24 + a44) * x2 * x2
                + (2 * a04 - 6 * a44) * x2 * y2 + (a04 - a24 + a44) * y2 * y2)

    terms = ("02", "22", "04", "24", "44")
    warped = np.column_stack([x * polar([c[f"cx{t}"] for t in terms]), y * polar([c[f"cy{t}"] for t in terms])])
    after = rot @ np.diag([c["squeeze_x"], c["squeeze_y"]]) @ P
    return warped @ after.T


def _fisheye(p, c, focal_dn):
    r = np.hypot(p[:, 0], p[:, 1])
    theta = 2 * np.arcsin(r / (2 * focal_dn))
    plain = p * np.where(r > 0, focal_dn * np.tan(theta) / np.where(r > 0, r, 1), 1.0)[:, None]
    s2 = np.sum(plain**2, axis=1)
    return plain * (1 + c["c2"] * s2 + c["c4"] * s2**2 + c["c6"] * s2**3 + c["c8"] * s2**4)[:, None]


def undistort_dn(model, c, p, pixel_aspect=1.0, focal_dn=1.0):
    """LDPK's ``undistort`` of ``model`` with coefficients ``c`` (camcal's keys) at distorted points ``p``."""
    if model == "3de-classic":
        return _classic(p, c)
    if model == "3de4-radial-deg4":
        return _radial(p, c)
    if model == "3de4-anamorphic-deg4":
        return _anamorphic(p, c, pixel_aspect)
    return _fisheye(p, c, focal_dn)


def undistort_pixels(model, c, pixels, image_size, filmback, lens_centre, pixel_aspect, focal):
    """Nuke's / 3DE's pipeline on camcal pixels: unit coordinates (origin lower left, pixel centres at (i + 1/2)/W),
    the film back ``(w, h)`` with the lens-centre offset ``(x, y)`` (any one length unit), diagonal normalisation,
    the model, and back to pixels."""
    width, height = image_size
    w_fb, h_fb = filmback
    r_fb = 0.5 * np.hypot(w_fb, h_fb)
    unit = np.column_stack([(pixels[:, 0] + 0.5) / width, 1 - (pixels[:, 1] + 0.5) / height])
    p = np.column_stack([((unit[:, 0] - 0.5) * w_fb - lens_centre[0]) / r_fb,
                         ((unit[:, 1] - 0.5) * h_fb - lens_centre[1]) / r_fb])
    q = undistort_dn(model, c, p, pixel_aspect, focal / r_fb)
    unit_q = np.column_stack([0.5 + (q[:, 0] * r_fb + lens_centre[0]) / w_fb, 0.5 + (q[:, 1] * r_fb + lens_centre[1]) / h_fb])
    return np.column_stack([unit_q[:, 0] * width - 0.5, (1 - unit_q[:, 1]) * height - 0.5])
