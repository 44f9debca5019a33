"""Peers on a raw chart's patches: OpenCV's cv2.ccm and colour-science's matrix_colour_correction, leave-one-out.

The patches are linear camera RGB (a raw file's) beside reference XYZ, so
cv2.ccm runs with its identity linearisation (``LINEARIZATION_IDENTITY``),
its 3x3 (``CCM_LINEAR``) and 4x3 (``CCM_AFFINE``) matrices fitted by
CIEDE2000 to the reference Lab (D50) and its output (linear sRGB, D65)
taken to XYZ and adapted back with Bradford, as OpenCV does; colour-science
fits ``matrix_colour_correction`` RGB -> XYZ directly (Cheung 2004 with 3,
5, 7, 8, 10 terms; Finlayson 2015 root-polynomial degrees 1-3; Vandermonde
degrees 1-2). Every figure is the mean CIEDE2000 (camcal.colour.difference)
against the same reference XYZ, training and leave-one-out.
"""

from __future__ import annotations

import cv2
import numpy as np

from camcal.colour.difference import XYZ_to_Lab, delta_E

OPENCV5_CCM = hasattr(cv2.ccm.ColorCorrectionModel, "compute")


def cv2_ccm_raw(RGB: np.ndarray, XYZ: np.ndarray, white_XYZ: np.ndarray) -> dict[str, tuple[float, float]]:
    """``{kind: (train mean, leave-one-out mean)}`` of cv2.ccm on linear RGB."""
    import colour

    lab_space = cv2.ccm.COLOR_SPACE_LAB_D50_2 if OPENCV5_CCM else cv2.ccm.COLOR_SPACE_Lab_D50_2
    D50 = colour.xy_to_XYZ(colour.CCS_ILLUMINANTS["CIE 1931 2 Degree Standard Observer"]["D50"])
    D65 = colour.xy_to_XYZ([0.3127, 0.3290])
    Lab = XYZ_to_Lab(colour.chromatic_adaptation(XYZ, white_XYZ, D50, method="Von Kries", transform="Bradford"), D50)

    def fit(src, lab, shape):
        m = cv2.ccm.ColorCorrectionModel(src.reshape(-1, 1, 3).astype(np.float64),
                                         lab.reshape(-1, 1, 3).astype(np.float64), lab_space)
        if OPENCV5_CCM:
            m.setCcmType(cv2.ccm.CCM_LINEAR if shape == "3x3" else cv2.ccm.CCM_AFFINE)
            m.setLinearization(cv2.ccm.LINEARIZATION_IDENTITY)
        else:
            m.setCCM_TYPE(cv2.ccm.CCM_3x3 if shape == "3x3" else cv2.ccm.CCM_4x3)
            m.setLinear(cv2.ccm.LINEARIZATION_IDENTITY)
        m.setDistance(cv2.ccm.DISTANCE_CIE2000)
        m.compute() if OPENCV5_CCM else m.run()
        return m

    def predict(m, src):
        if OPENCV5_CCM:
            m.setRGB(False)
            enc = m.correctImage(src.reshape(-1, 1, 3).astype(np.float32)).reshape(-1, 3).astype(np.float64)
            lin = np.sign(enc) * colour.cctf_decoding(np.abs(enc), function="sRGB")
        else:
            lin = m.infer(src.reshape(-1, 1, 3).astype(np.float64), True).reshape(-1, 3)
        out = colour.RGB_to_XYZ(lin, colour.RGB_COLOURSPACES["sRGB"], apply_cctf_decoding=False)
        return colour.chromatic_adaptation(out, D65, white_XYZ, method="Von Kries", transform="Bradford")

    figures = {}
    n = len(RGB)
    for shape in ("3x3", "4x3"):
        m = fit(RGB, Lab, shape)
        train = float(delta_E(predict(m, RGB), XYZ, white_XYZ).mean())
        loo = [float(delta_E(predict(fit(RGB[np.arange(n) != i], Lab[np.arange(n) != i], shape), RGB[i:i + 1]),
                             XYZ[i:i + 1], white_XYZ)[0]) for i in range(n)]
        figures[f"cv2.ccm {shape} identity"] = (train, float(np.mean(loo)))
    return figures


COLOUR_SCIENCE_METHODS = ([("Cheung 2004", {"terms": t}) for t in (3, 5, 7, 8, 10)]
                          + [("Finlayson 2015", {"degree": d}) for d in (1, 2, 3)]
                          + [("Vandermonde", {"degree": d}) for d in (1, 2)])


def colour_science_raw(RGB: np.ndarray, XYZ: np.ndarray, white_XYZ: np.ndarray) -> dict[str, tuple[float, float]]:
    """``{method: (train mean, leave-one-out mean)}`` of colour-science's matrix_colour_correction."""
    import colour

    figures = {}
    n = len(RGB)
    for method, kw in COLOUR_SCIENCE_METHODS:
        M = colour.characterisation.matrix_colour_correction(RGB, XYZ, method=method, **kw)
        train = colour.characterisation.apply_matrix_colour_correction(RGB, M, method=method, **kw)
        loo = []
        for i in range(n):
            keep = np.arange(n) != i
            Mi = colour.characterisation.matrix_colour_correction(RGB[keep], XYZ[keep], method=method, **kw)
            loo.append(colour.characterisation.apply_matrix_colour_correction(RGB[i:i + 1], Mi, method=method, **kw))
        label = f"{method} " + ",".join(f"{k}={v}" for k, v in kw.items())
        figures[label] = (float(delta_E(train, XYZ, white_XYZ).mean()),
                          float(delta_E(np.vstack(loo), XYZ, white_XYZ).mean()))
    return figures
