import cv2
import numpy as np
import pytest

from camcal.colour.chart.detect import chart_from_corners, detect_chart, sample_patches
from camcal.io.colourimage import read_image
from camcal.colour.chart.reference import reference_chart
from camcal.colour.fit.characterise import characterise
from camcal.pipelines.colour import patches_from_chart
from camcal.colour.difference import XYZ_to_Lab, delta_E
from camcal.base.errors import CamcalError

CORNERS = np.array([[150, 120], [500, 110], [510, 350], [140, 360]], float)


def render_chart(ref, corners=CORNERS, size=(480, 640), gap=0.15, noise=0.004, seed=0):
    """A synthetic photo: the chart's sRGB colours on a dark body, in perspective."""
    import colour

    D65 = colour.xy_to_XYZ([0.3127, 0.3290])
    codes = np.clip(colour.XYZ_to_sRGB(colour.chromatic_adaptation(ref.XYZ, ref.white_XYZ, D65,
                                                                   transform="CAT02")), 0, 1)
    img = np.full(size + (3,), 0.35)
    H = chart_from_corners(corners).H

    def poly(uv):
        p = np.column_stack([uv, np.ones(len(uv))]) @ H.T
        return np.round(p[:, :2] / p[:, 2:]).astype(np.int32)

    cv2.fillConvexPoly(img, poly(np.array([[-0.05, -0.08], [1.05, -0.08], [1.05, 1.08], [-0.05, 1.08]])),
                       (0.05, 0.05, 0.05))
    for i in range(24):
        r, c = divmod(i, 6)
        u0, u1, v0, v1 = (c + gap / 2) / 6, (c + 1 - gap / 2) / 6, (r + gap / 2) / 4, (r + 1 - gap / 2) / 4
        cv2.fillConvexPoly(img, poly(np.array([[u0, v0], [u1, v0], [u1, v1], [u0, v1]])),
                           tuple(float(v) for v in codes[i]))
    img = img + np.random.default_rng(seed).normal(0, noise, img.shape)
    return np.round(np.clip(img, 0, 1) * 255) / 255, codes


def test_reference_chart_values():
    ref = reference_chart("cc24")
    assert ref.name == "ColorChecker24 - After November 2014" and ref.XYZ.shape == (24, 3)
    np.testing.assert_array_equal(ref.neutral, np.arange(18, 24))
    assert ref.XYZ[18, 1] == pytest.approx(0.9, abs=0.05)  # white 9.5
    np.testing.assert_allclose(XYZ_to_Lab(ref.XYZ[18], ref.white_XYZ)[1:], 0, atol=4)
    sg = reference_chart("sg")
    assert sg.XYZ.shape == (140, 3) and (sg.rows, sg.columns) == (10, 14)
    iso = reference_chart("ISO 17321-1", "D65")
    assert iso.white_XYZ[1] == pytest.approx(1.0)
    d65 = reference_chart("cc24", "D65")
    assert delta_E(d65.XYZ, ref.XYZ, ref.white_XYZ).mean() > 1  # adapted, not relabelled
    with pytest.raises(CamcalError, match="unknown reference chart 'cc25'"):
        reference_chart("cc25")


def test_manual_corners_sample_the_true_colours():
    img, codes = render_chart(reference_chart())
    s = sample_patches(img, chart_from_corners(CORNERS))
    ok = ~s.clipped
    np.testing.assert_allclose(s.RGB[ok], codes[ok], atol=0.004)
    assert s.clipped.sum() >= 1  # sRGB-out-of-gamut patches clip at 0 or 1


def test_cv2_mcc_detection_on_a_synthetic_photo():
    img, codes = render_chart(reference_chart())
    det = detect_chart(img, detector="cv2.mcc")
    assert det.method == "cv2.mcc"
    np.testing.assert_allclose(det.patch_centres(), chart_from_corners(CORNERS).patch_centres(), atol=6)
    s = sample_patches(img, det)
    np.testing.assert_allclose(s.RGB[~s.clipped], codes[~s.clipped], atol=0.004)


def test_no_chart_says_so():
    with pytest.raises(CamcalError, match="no ColorChecker found"):
        detect_chart(np.full((300, 400, 3), 0.5))


def test_bad_corners_and_missing_image(tmp_path):
    with pytest.raises(CamcalError, match="4 corners"):
        chart_from_corners([[0, 0], [1, 1]])
    with pytest.raises(CamcalError, match="no area"):
        chart_from_corners([[0, 0], [1, 0], [2, 0], [3, 0]])
    with pytest.raises(CamcalError, match="not found"):
        read_image(tmp_path / "missing.jpg")
    with pytest.raises(CamcalError, match="outside the image"):
        sample_patches(np.zeros((100, 100, 3)), chart_from_corners(CORNERS))


# OpenCV 5 moved cv2.ccm into the photo module and renamed its API: CCM_3x3 /
# CCM_4x3 -> CCM_LINEAR / CCM_AFFINE, setCCM_TYPE / setLinear* / run / infer ->
# setCcmType / setLinearization* / compute / correctImage, COLOR_SPACE_Lab_D50_2
# -> COLOR_SPACE_LAB_D50_2. correctImage (5.0.0) ignores its islinear flag and
# always returns sRGB-encoded values, and flips the channels unless setRGB(False).
# Its gray linearisations cannot run at all (5.0.0.93: cvtColor refuses the
# float64 source that saturate() requires), so on OpenCV 5 the second peer is
# the 4x3 matrix with a per-channel (colour) polyfit of degree 3 instead.
OPENCV5_CCM = hasattr(cv2.ccm.ColorCorrectionModel, "compute")
LAB_D50_2 = cv2.ccm.COLOR_SPACE_LAB_D50_2 if OPENCV5_CCM else cv2.ccm.COLOR_SPACE_Lab_D50_2


def _ccm_configure(m, shape, linearization, gamma=None, degree=None):
    """Matrix shape ("3x3" or "4x3") and linearisation on either OpenCV API."""
    if OPENCV5_CCM:
        m.setCcmType(cv2.ccm.CCM_LINEAR if shape == "3x3" else cv2.ccm.CCM_AFFINE)
        m.setLinearization(linearization)
        if gamma is not None:
            m.setLinearizationGamma(gamma)
        if degree is not None:
            m.setLinearizationDegree(degree)
    else:
        m.setCCM_TYPE(cv2.ccm.CCM_3x3 if shape == "3x3" else cv2.ccm.CCM_4x3)
        m.setLinear(linearization)
        if gamma is not None:
            m.setLinearGamma(gamma)
        if degree is not None:
            m.setLinearDegree(degree)


def _ccm_linear_output(m, src):
    """The model's linear sRGB output for ``(N, 3)`` code values ``src``."""
    if not OPENCV5_CCM:
        return m.infer(src.reshape(-1, 1, 3).astype(np.float64), True).reshape(-1, 3)
    import colour

    m.setRGB(False)
    encoded = m.correctImage(src.reshape(-1, 1, 3).astype(np.float32)).reshape(-1, 3).astype(np.float64)
    return np.sign(encoded) * colour.cctf_decoding(np.abs(encoded), function="sRGB")


def cv2_ccm_figures(patches, white_XYZ):
    """OpenCV cv2.ccm on the same patches: training and leave-one-out mean CIEDE2000.

    cv2.ccm fits code values to the reference Lab (D50) with its own
    linearisation; its output (linear sRGB, D65) goes to XYZ and is adapted
    to D50 with Bradford, as OpenCV does, before colour-science's CIEDE2000.
    (cv2.ccm's own getLoss() is the RMS, not the mean, of CIEDE2000.)
    """
    import colour

    Lab = XYZ_to_Lab(patches.XYZ, white_XYZ)
    D65 = colour.xy_to_XYZ([0.3127, 0.3290])

    def fit(src, lab, kind):
        m = cv2.ccm.ColorCorrectionModel(src.reshape(-1, 1, 3).astype(np.float64),
                                         lab.reshape(-1, 1, 3).astype(np.float64),
                                         LAB_D50_2)
        if kind == "3x3 gamma 2.2":
            _ccm_configure(m, "3x3", cv2.ccm.LINEARIZATION_GAMMA, gamma=2.2)
        elif kind == "4x3 gray polyfit 3":
            _ccm_configure(m, "4x3", cv2.ccm.LINEARIZATION_GRAYPOLYFIT, degree=3)
        else:
            _ccm_configure(m, "4x3", cv2.ccm.LINEARIZATION_COLORPOLYFIT, degree=3)
        m.setDistance(cv2.ccm.DISTANCE_CIE2000)
        m.compute() if OPENCV5_CCM else m.run()
        return m

    def to_XYZ(m, src):
        lin = _ccm_linear_output(m, src)
        XYZ = colour.RGB_to_XYZ(lin, colour.RGB_COLOURSPACES["sRGB"], apply_cctf_decoding=False)
        return colour.chromatic_adaptation(XYZ, D65, white_XYZ, method="Von Kries", transform="Bradford")

    out = {}
    N = len(patches)
    for kind in ("3x3 gamma 2.2", "4x3 colour polyfit 3" if OPENCV5_CCM else "4x3 gray polyfit 3"):
        m = fit(patches.RGB, Lab, kind)
        train = delta_E(to_XYZ(m, patches.RGB), patches.XYZ, white_XYZ).mean()
        loo = []
        for i in range(N):
            keep = np.arange(N) != i
            mi = fit(patches.RGB[keep], Lab[keep], kind)
            loo.append(delta_E(to_XYZ(mi, patches.RGB[i : i + 1]), patches.XYZ[i : i + 1], white_XYZ)[0])
        out[kind] = (float(train), float(np.mean(loo)), float(m.getLoss()))
    return out


def test_real_chart_photo_against_cv2_ccm(shared_data):
    path = shared_data / "colorchecker_photo" / "img-colorchecker.jpg"
    found = patches_from_chart(path)
    assert found.detection.method == "segmentation"
    assert found.detection.fit_rms_px < 1.0
    # cv2.mcc finds the same chart, in the same order: every patch centre within 0.15 of the patch pitch
    # (the sampled square reaches 0.25 of it from the centre; cv2.mcc's centres sit up to 6.6 px, 0.13 pitch,
    # below the top row's, seen on an overlay of both)
    mcc = detect_chart(read_image(path), detector="cv2.mcc")
    pitch = np.linalg.norm(np.diff(mcc.patch_centres()[:2], axis=0))
    assert np.abs(mcc.patch_centres() - found.detection.patch_centres()).max() < 0.15 * pitch
    assert len(found.patches) >= 20  # yellow and cyan clip at 0 in this JPEG
    outcome = characterise(found.patches, white="D50", model="auto", linearise="lut1d",
                           reference=found.reference.name)
    ours = outcome.result
    peer = cv2_ccm_figures(found.patches, found.reference.white_XYZ)
    print(f"real photo, {len(found.patches)} patches (dropped: {', '.join(found.excluded)}): "
          f"camcal {ours.model.label} ({outcome.fit.model.objective}) train {ours.stats_train.mean:.2f} "
          f"LOO {ours.stats_loo.mean:.2f}")
    for kind, (train, loo, loss) in peer.items():
        print(f"  cv2.ccm {kind}: train {train:.2f} LOO {loo:.2f} (getLoss, RMS: {loss:.2f})")
    assert outcome.fit.linearisation.residual < 0.01
    assert ours.stats_loo.mean < min(loo for _, loo, _ in peer.values())


def test_no_colorchecker_on_real_chessboard_photos(shared_data):
    """A chessboard is a lattice of squares too: its greys do not agree with the chart's colours, so neither
    detector (segmentation, then cv2.mcc with its order checked) reports a ColorChecker, as a photo or as a raw
    view (measured: none on 39 chessboard photos of five cameras)."""
    from camcal.colour.chart.detect import reference_linear_RGB

    reference = reference_linear_RGB(reference_chart())
    for path in sorted((shared_data / "stereo_chessboard").glob("*.jpg"))[::10]:
        image = read_image(path)
        for linear in (False, True):
            with pytest.raises(CamcalError, match="no ColorChecker found"):
                detect_chart(image, reference_RGB=reference, linear=linear)
