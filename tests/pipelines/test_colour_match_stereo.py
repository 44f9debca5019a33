"""Colour match, image route: a synthetic rectified stereo pair with a known colour transform.

Camera B sees the scene's linear RGB ``S`` (the right view); camera A (left
view) sees ``G(S)`` for a known ``G``; both get 0.3 % multiplicative noise.
About 10 % of B's pixels are outliers (speculars: white added; mismatches:
another surface's colour), and a foreground box occludes part of the
background in the other view.
"""

from dataclasses import dataclass

import cv2
import numpy as np
import pytest

from camcal.colour.difference import delta_E
from camcal.colour.match.routes import REC709_SPACE, rec709_XYZ
from camcal.pipelines.colour import match_images
from camcal.geometry.correspondence import stereo_correspondences
from camcal.report.colour_match import write_report
from camcal.base.errors import CamcalError
from camcal.synthetic import layered_stereo_pair

NOISE = 0.003
M_TRUE = np.array([[1.10, -0.08, 0.03], [0.05, 0.93, 0.04], [-0.02, 0.09, 0.88]])
D65 = np.array([0.95047, 1.0, 1.08883])


def G_matrix(b):
    return b @ M_TRUE.T


def G_curved(b):
    x = b @ M_TRUE.T
    return x * (1 + 0.25 * (x - 0.45))


@dataclass
class Pair:
    A: np.ndarray
    B: np.ndarray
    disparity: np.ndarray
    occluded: np.ndarray
    outliers: np.ndarray


def make_pair(G, seed=1, outlier_fraction=0.10):
    rng = np.random.default_rng(seed)
    left, right, disparity, occluded = layered_stereo_pair(rng)
    A = G(left) * (1 + NOISE * rng.standard_normal(left.shape))
    B = right * (1 + NOISE * rng.standard_normal(right.shape))
    height, width = B.shape[:2]
    outliers = np.zeros((height, width), bool)
    for kind in ("specular", "mismatch"):
        blobs = np.zeros((height, width), np.uint8)
        while blobs.mean() < outlier_fraction / 2:
            centre = (int(rng.integers(0, width)), int(rng.integers(0, height)))
            cv2.circle(blobs, centre, int(rng.integers(4, 12)), 1, -1)
        blobs = blobs > 0
        if kind == "specular":
            B[blobs] += 0.25
        else:
            B[blobs] = 0.8 * B[blobs][:, [2, 0, 1]]
        outliers |= blobs
    return Pair(A, B, disparity, occluded, outliers)


@pytest.fixture(scope="module")
def pair():
    return make_pair(G_matrix)


def _delta_E_vs_truth(match, G, source):
    """CIEDE2000 between the recovered and the true transform on the same B colours (Rec. 709 XYZ)."""
    return delta_E(rec709_XYZ(match.apply(source)), rec709_XYZ(G(source)), D65)


def test_pair_has_ten_percent_outliers(pair):
    share = pair.outliers.mean()
    assert 0.09 < share < 0.13


def test_correspondences_follow_true_disparity_and_drop_occlusions(pair):
    corr = stereo_correspondences(pair.A, pair.B)
    assert corr.a_is_left
    valid = corr.valid
    assert valid.mean() > 0.4
    error = np.abs(corr.disparity[valid] - pair.disparity[valid])
    assert np.median(error) < 0.25 and np.mean(error > 1.0) < 0.01
    # the left-right check and the depth-edge filter reject the occluded pixels
    assert np.mean(valid[pair.occluded]) < 0.02
    # swapped views: A is the right view, found without being told
    swapped = stereo_correspondences(pair.B, pair.A)
    assert not swapped.a_is_left and swapped.valid.mean() > 0.4


def test_robust_match_recovers_the_transform_least_squares_does_not(pair):
    robust = match_images(pair.A, pair.B, model="matrix3x3")
    plain = match_images(pair.A, pair.B, model="matrix3x3", robust="none")
    np.testing.assert_array_equal(robust.test_source, plain.test_source)  # same held-out pixels
    dE_robust = _delta_E_vs_truth(robust.match, G_matrix, robust.test_source)
    dE_plain = _delta_E_vs_truth(plain.match, G_matrix, plain.test_source)
    print(f"held-out CIEDE2000 vs the true transform: robust mean {dE_robust.mean():.3f}, "
          f"least squares mean {dE_plain.mean():.3f}")
    assert dE_robust.mean() < 0.5
    assert dE_plain.mean() > 0.5 and dE_plain.mean() > 10 * dE_robust.mean()
    # the matrix itself: within a few noise sigmas of the truth (per coefficient)
    np.testing.assert_allclose(robust.match.matrix, M_TRUE, atol=5 * NOISE)
    # file figures: held-out inliers drop from the unmatched difference to the noise level
    ev = robust.match.evaluation
    assert ev["space"] == REC709_SPACE
    assert ev["before"]["mean"] > 2.0 and ev["test"]["mean"] < 0.3
    assert ev["test"]["n"] + ev["n_test_outliers"] == len(robust.test_source)
    # held-out pixels flagged as outliers are mostly the planted ones
    flagged = ~robust.test_inliers
    assert flagged.sum() > 0.05 * len(flagged)


def test_robust_root_polynomial_also_recovers_a_matrix(pair):
    result = match_images(pair.A, pair.B, model="root-polynomial:2", robust="irls")
    assert _delta_E_vs_truth(result.match, G_matrix, result.test_source).mean() < 0.5


def test_lut_and_polynomial_follow_a_curved_transform_better_than_a_matrix():
    curved = make_pair(G_curved, seed=2)
    figures = {}
    for model in ("matrix3x3", "lut3d:9"):
        result = match_images(curved.A, curved.B, model=model)
        figures[model] = _delta_E_vs_truth(result.match, G_curved, result.test_source).mean()
    assert figures["lut3d:9"] < 0.5
    assert figures["lut3d:9"] < 0.5 * figures["matrix3x3"]


def test_report_images(tmp_path, pair):
    result = match_images(pair.A, pair.B, model="matrix3x3")
    files = write_report(result, tmp_path)
    names = {p.name for p in files}
    assert {"difference_before.png", "difference_after.png", "delta_E_before.png", "delta_E_after.png",
            "valid.png", "summary.txt"} <= names
    after = cv2.imread(str(tmp_path / "difference_after.png")).astype(float)
    before = cv2.imread(str(tmp_path / "difference_before.png")).astype(float)
    assert after.shape == (240, 320, 3) and after.mean() < before.mean()
    assert "held out" in (tmp_path / "summary.txt").read_text()


def test_image_route_bad_input(pair):
    with pytest.raises(CamcalError, match="one size"):
        match_images(pair.A, pair.B[:, :-1])
    flat = np.full_like(pair.A, 0.5)
    with pytest.raises(CamcalError, match="too few reliable correspondences"):
        match_images(flat, flat)
    with pytest.raises(CamcalError, match="test_fraction"):
        match_images(pair.A, pair.B, test_fraction=1.5)
