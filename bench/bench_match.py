"""Benchmark: camcal's robust colour match vs OpenCV's cv2.ccm and plain least squares.

Data: a synthetic rectified stereo pair (camcal.synthetic.layered_stereo_pair,
640x480), camera A = a known 3x3 matrix of camera B's linear RGB, 0.3 %
multiplicative noise on both, 10 % of B's pixels outliers (speculars: white
added; mismatches: another surface's colour). Every method gets the SAME
correspondences (camcal's SGBM + left-right check + filters) and training
pixels; each is judged by CIEDE2000 between its transform and the true one
on the held-out pixels' B colours (A's RGB read as linear Rec. 709, D65).

Peers: ``cv2.ccm.ColorCorrectionModel`` (CCM_3x3, identity linearisation,
linear-sRGB colour space, RGBL distance, least-squares start) and
``numpy.linalg.lstsq`` (ordinary least squares). Neither rejects outliers.

Run with ``make bench`` or ``.venv/bin/python bench/bench_match.py``; lines
follow ``name: ours X, peer Y, ratio Y/X``.
"""

from __future__ import annotations

import time

import cv2
import numpy as np

from camcal.colour.difference import delta_E
from camcal.pipelines.colour import match_images
from camcal.colour.match.routes import rec709_XYZ
from camcal.colour.match.robust import fit_match_model
from camcal.synthetic import layered_stereo_pair

M_TRUE = np.array([[1.10, -0.08, 0.03], [0.05, 0.93, 0.04], [-0.02, 0.09, 0.88]])
D65 = np.array([0.95047, 1.0, 1.08883])


def make_pair(seed: int = 1, width: int = 640, height: int = 480):
    rng = np.random.default_rng(seed)
    left, right, _, _ = layered_stereo_pair(rng, width, height, background=(16, 32), foreground=56)
    A = (left @ M_TRUE.T) * (1 + 0.003 * rng.standard_normal(left.shape))
    B = right * (1 + 0.003 * rng.standard_normal(right.shape))
    for kind in ("specular", "mismatch"):
        blobs = np.zeros((height, width), np.uint8)
        while blobs.mean() < 0.05:
            centre = (int(rng.integers(0, width)), int(rng.integers(0, height)))
            cv2.circle(blobs, centre, int(rng.integers(8, 24)), 1, -1)
        blobs = blobs > 0
        B[blobs] = B[blobs] + 0.25 if kind == "specular" else 0.8 * B[blobs][:, [2, 0, 1]]
    return A, B


def cv2_ccm(B: np.ndarray, A: np.ndarray) -> np.ndarray:
    if hasattr(cv2.ccm.ColorCorrectionModel, "compute"):  # OpenCV 5 renamed the ccm API
        model = cv2.ccm.ColorCorrectionModel(B.reshape(-1, 1, 3), A.reshape(-1, 1, 3), cv2.ccm.COLOR_SPACE_SRGBL)
        model.setCcmType(cv2.ccm.CCM_LINEAR)
        model.setLinearization(cv2.ccm.LINEARIZATION_IDENTITY)
        model.setDistance(cv2.ccm.DISTANCE_RGBL)
        model.setInitialMethod(cv2.ccm.INITIAL_METHOD_LEAST_SQUARE)
        return model.compute().T
    model = cv2.ccm_ColorCorrectionModel(B.reshape(-1, 1, 3), A.reshape(-1, 1, 3), cv2.ccm.COLOR_SPACE_sRGBL)
    model.setCCM_TYPE(cv2.ccm.CCM_3x3)
    model.setLinear(cv2.ccm.LINEARIZATION_IDENTITY)
    model.setDistance(cv2.ccm.DISTANCE_RGBL)
    model.setInitialMethod(cv2.ccm.INITIAL_METHOD_LEAST_SQUARE)
    model.run()
    return model.getCCM().T


def timed(function, *args, repeat: int = 3):
    best, out = np.inf, None
    for _ in range(repeat):
        start = time.perf_counter()
        out = function(*args)
        best = min(best, time.perf_counter() - start)
    return out, best


def main() -> None:
    A, B = make_pair()
    result = match_images(A, B, model="matrix3x3")
    train_B, train_A, test_B = result.train_source, result.train_target, result.test_source
    truth = rec709_XYZ(test_B @ M_TRUE.T)

    def error(M: np.ndarray) -> float:
        return float(np.mean(delta_E(rec709_XYZ(test_B @ M.T), truth, D65)))

    ours, t_ours = timed(lambda: fit_match_model(train_B, train_A, "matrix3x3").model.M)
    lstsq, t_lstsq = timed(lambda: np.linalg.lstsq(train_B, train_A, rcond=None)[0].T)
    ccm, t_ccm = timed(cv2_ccm, train_B, train_A)
    counts = result.correspondences.counts
    print(f"pair 640x480: {counts['valid']} kept pixels, {len(train_B)} in the fit, {len(test_B)} held out")
    e_ours, e_ccm, e_lstsq = error(ours), error(ccm), error(lstsq)
    print(f"match held-out dE2000 vs truth (cv2.ccm): ours {e_ours:.4f}, peer {e_ccm:.4f}, ratio {e_ccm / e_ours:.1f}")
    print(f"match held-out dE2000 vs truth (least squares): ours {e_ours:.4f}, peer {e_lstsq:.4f}, "
          f"ratio {e_lstsq / e_ours:.1f}")
    print(f"match fit time s (cv2.ccm): ours {t_ours:.3f}, peer {t_ccm:.3f}, ratio {t_ccm / t_ours:.2f}")
    print(f"match fit time s (least squares): ours {t_ours:.3f}, peer {t_lstsq:.4f}, ratio {t_lstsq / t_ours:.3f}")


if __name__ == "__main__":
    main()
