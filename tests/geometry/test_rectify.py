"""Rectification: synthetic rigs of known geometry, OpenCV as a peer, the real stereo set."""

import dataclasses
import itertools
import math
import warnings

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from camcal.cli import main
from camcal.base.errors import CamcalError
from camcal.model.distortion import Distortion
from camcal.geometry.rectify import (
    CentresOffLineWarning,
    RectifyWarper,
    image_deformation,
    rectify,
    rectify_calibrated,
    rectify_Hartley1999,
    rectify_Nozick2011,
    vertical_disparity,
)
from camcal.io.matches import read_matches_csv
from camcal.model.rig import Camera, Rig
from camcal.pipelines.rectify import match_image_files

SIZE = (1280, 720)
SIGMA_PX = 0.2
DISTORTIONS = (
    Distortion("opencv", {"k1": -0.12, "k2": 0.03, "p1": 4e-4, "p2": -3e-4, "k3": 0.0}),
    Distortion("division", {"lambda": -1.5e-7}),
    Distortion("polynomial", {"k1": 0.05, "k2": -0.01}),
)


def line_rig(n, rng, baseline=0.25, max_angle_deg=5.0, offsets=None, distortions=DISTORTIONS):
    """n cameras on the world x axis looking along +z, small random rotations."""
    cameras = []
    for i in range(n):
        axis = rng.normal(size=3)
        angle = math.radians(rng.uniform(0.5, max_angle_deg))
        R = Rotation.from_rotvec(axis / np.linalg.norm(axis) * angle).as_matrix()
        f = 1000.0 + 20.0 * i
        K = np.array([[f, 0.0, 640.0 + 5 * i], [0.0, f * 0.998, 360.0 - 3 * i], [0.0, 0.0, 1.0]])
        c = np.array([i * baseline, 0.0, 0.0]) + (0.0 if offsets is None else offsets[i])
        cameras.append(Camera(f"cam{i}", SIZE, K, distortions[i % len(distortions)], R, c))
    return Rig(tuple(cameras), units="m")


def scene_matches(rig, rng, n_points, sigma=0.0):
    """Points 3-10 m in front of the rig; matches between every pair that sees them."""
    X = np.column_stack([rng.uniform(-2.5, 3.5, n_points), rng.uniform(-1.5, 1.5, n_points),
                         rng.uniform(3.0, 10.0, n_points)])
    seen = {}
    for camera in rig.cameras:
        x = camera.project(X)
        ok = np.all(np.isfinite(x), axis=1) & (x[:, 0] > 0) & (x[:, 0] < SIZE[0] - 1) & (x[:, 1] > 0) & (x[:, 1] < SIZE[1] - 1)
        seen[camera.name] = (x + rng.normal(0.0, sigma, x.shape), ok)
    matches = {}
    for a, b in itertools.combinations([c.name for c in rig.cameras], 2):
        both = seen[a][1] & seen[b][1]
        matches[(a, b)] = (seen[a][0][both], seen[b][0][both])
    return matches


def perturbed(rig, rng, angle_deg=0.15, focal=0.004):
    """The rig as an imperfect calibration sees it: rotations and focal lengths off."""
    cameras = []
    for camera in rig.cameras:
        axis = rng.normal(size=3)
        dR = Rotation.from_rotvec(axis / np.linalg.norm(axis) * math.radians(angle_deg)).as_matrix()
        K = camera.K.copy()
        K[:2, :2] *= 1.0 + rng.uniform(-focal, focal)
        cameras.append(dataclasses.replace(camera, R=dR @ camera.R, K=K))
    return dataclasses.replace(rig, cameras=tuple(cameras))


def all_rms(disparities):
    d2 = sum(p.rms_px**2 * p.n for p in disparities)
    return math.sqrt(d2 / sum(p.n for p in disparities))


@pytest.mark.parametrize("n", [2, 3, 5])
def test_calibrated_rectification_aligns_rows_exactly(n):
    rng = np.random.default_rng(n)
    rig = line_rig(n, rng)
    result = rectify_calibrated(rig, alpha=0.0)
    held_out = scene_matches(rig, rng, 400)
    disparity = vertical_disparity(result.rig, held_out)
    assert len(disparity) == n * (n - 1) // 2 and all(p.n > 50 for p in disparity)
    assert max(p.max_px for p in disparity) < 1e-6
    # one shared K_rect, x along the line of centres, y down like the cameras
    for camera in result.rig.cameras:
        assert np.array_equal(camera.rectification.K_rect, result.K_rect)
        assert camera.rectification.image_size == result.image_size
    assert np.allclose(result.R_rect[0], [1.0, 0.0, 0.0], atol=1e-12)
    assert result.R_rect[1] @ np.mean([c.R[1] for c in rig.cameras], axis=0) > 0.99
    assert result.line_offset_ratio < 1e-12
    # alpha = 0 keeps no invalid pixel; the kept share is large for 5 deg rotations
    for item in result.deformation:
        assert item.valid_fraction > 0.999
        assert 0.6 < item.kept_fraction <= 1.0
        assert abs(item.orthogonality_deg - 90.0) < 3.0 and abs(item.aspect_ratio - 1.0) < 0.05


@pytest.mark.parametrize("seed", range(6))
def test_two_view_rotation_is_opencv_stereoRectify_s(seed):
    # the one free choice of a calibrated rectification (a rotation about the baseline): camcal takes
    # the rotation nearest the cameras' mean one, which for two cameras is cv2.stereoRectify's
    rng = np.random.default_rng(100 + seed)
    rig = line_rig(2, rng, max_angle_deg=8.0)
    for first, second in (rig.cameras, rig.cameras[::-1]):  # the second camera right, then left
        result = rectify_calibrated(Rig((first, second)))
        R = second.R @ first.R.T
        T = second.R @ (first.c - second.c)
        R1, R2, *_ = cv2.stereoRectify(first.K, np.zeros(5), second.K, np.zeros(5), SIZE, R, T.reshape(3, 1))
        for R_cv, camera in ((R1, first), (R2, second)):
            assert Rotation.from_matrix(R_cv @ camera.R @ result.R_rect.T).magnitude() < 1e-12


def test_N_view_rotation_is_the_rectifying_rotation_nearest_the_mean():
    rng = np.random.default_rng(21)
    rig = line_rig(4, rng, max_angle_deg=8.0, offsets=[np.zeros(3), [0.0, 0.002, 0.0], [0.0, -0.001, 0.003], np.zeros(3)])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", CentresOffLineWarning)
        result = rectify_calibrated(rig)
    mean = Rotation.from_matrix(np.array([c.R for c in rig.cameras])).mean()
    centres = np.array([c.c for c in rig.cameras])
    direction = np.linalg.svd(centres - centres.mean(axis=0))[2][0]
    assert abs(abs(result.R_rect[0] @ direction) - 1.0) < 1e-12
    distance = (Rotation.from_matrix(result.R_rect) * mean.inv()).magnitude()
    for angle in (-1e-3, 1e-3, -0.1, 0.1):  # every other rectifying rotation: turned about the baseline
        other = Rotation.from_rotvec([angle, 0.0, 0.0]) * Rotation.from_matrix(result.R_rect)
        assert (other * mean.inv()).magnitude() > distance


def test_H_is_K_rect_R_rect_R_i_transpose_K_i_inverse():
    rng = np.random.default_rng(11)
    rig = line_rig(2, rng)
    result = rectify_calibrated(rig)
    for camera in result.rig.cameras:
        expected = result.K_rect @ result.R_rect @ camera.R.T @ np.linalg.inv(camera.K)
        H = camera.rectification.H
        assert np.allclose(H / H[2, 2], expected / expected[2, 2], rtol=1e-10, atol=1e-12)


def test_alpha_one_keeps_every_source_pixel():
    rng = np.random.default_rng(12)
    rig = line_rig(3, rng)
    tight, loose = rectify_calibrated(rig, alpha=0.0), rectify_calibrated(rig, alpha=1.0)
    assert all(item.kept_fraction > 0.999 for item in loose.deformation)
    assert all(item.valid_fraction < 0.99 for item in loose.deformation)
    assert loose.image_size[0] > tight.image_size[0] and loose.image_size[1] > tight.image_size[1]


@pytest.mark.parametrize("n", [2, 3, 5])
def test_nozick_refinement_corrects_an_imperfect_calibration(n):
    rng = np.random.default_rng(100 + n)
    truth = line_rig(n, rng)
    calibration = perturbed(truth, rng)
    training = scene_matches(truth, rng, 300, sigma=SIGMA_PX)
    held_out = scene_matches(truth, rng, 300)
    held_out_noisy = scene_matches(truth, rng, 300, sigma=SIGMA_PX)
    before = all_rms(vertical_disparity(rectify_calibrated(calibration).rig, held_out))
    result = rectify_Nozick2011(calibration, training)
    after = all_rms(vertical_disparity(result.rig, held_out))
    noisy = all_rms(vertical_disparity(result.rig, held_out_noisy))
    assert before > 1.0  # the calibration error is visible
    assert after < 0.3 * SIGMA_PX / 0.2  # the 0.3 px at sigma = 0.2 px
    # noisy held-out matches: the noise of two images (sqrt(2) sigma) and nothing more
    scale = result.K_rect[0, 0] / np.mean([c.K[0, 0] for c in truth.cameras])
    assert noisy < 1.15 * math.sqrt(2.0) * SIGMA_PX * scale + after
    assert noisy > 0.8 * math.sqrt(2.0) * SIGMA_PX * scale


def test_nozick_without_noise_is_exact_on_an_exact_calibration():
    rng = np.random.default_rng(7)
    rig = line_rig(3, rng)
    result = rectify_Nozick2011(rig, scene_matches(rig, rng, 200))
    assert max(p.max_px for p in vertical_disparity(result.rig, scene_matches(rig, rng, 200))) < 1e-6


def test_centres_off_the_line_warn_with_the_figure():
    rng = np.random.default_rng(3)
    baseline, e = 0.25, 0.01
    offsets = [np.zeros(3), np.array([0.0, e, 0.0]), np.zeros(3)]
    rig = line_rig(3, rng, baseline=baseline, offsets=offsets)
    # the least-squares line through (0, 0), (b, e), (2b, 0) is y = e/3: distances e/3, 2e/3, e/3
    expected = (2 * e / 3) / (2 * baseline)
    with pytest.warns(CentresOffLineWarning, match=f"{expected:.3%}".replace(".", r"\.")) as record:
        result = rectify_calibrated(rig)
    assert "'cam1'" in str(record[0].message)
    assert result.line_offset_ratio == pytest.approx(expected, rel=1e-9)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        rectify_calibrated(rig, max_offset_ratio=0.02)


def test_impossible_rectifications_are_refused():
    rng = np.random.default_rng(5)
    rig = line_rig(2, rng)
    same = dataclasses.replace(rig, cameras=(rig.cameras[0], dataclasses.replace(rig.cameras[1], c=rig.cameras[0].c)))
    with pytest.raises(CamcalError, match="centres coincide"):
        rectify_calibrated(same)
    forward = dataclasses.replace(rig, cameras=(rig.cameras[0], dataclasses.replace(rig.cameras[1], c=np.array([0.0, 0.0, 1.0]))))
    with pytest.raises(CamcalError, match="epipole .* inside the image"):
        rectify_calibrated(forward)
    with pytest.raises(CamcalError, match="at least 2 cameras"):
        rectify_calibrated(rig, names=["cam0"])
    with pytest.raises(CamcalError, match="alpha"):
        rectify_calibrated(rig, alpha=1.5)
    with pytest.raises(CamcalError, match="needs point matches"):
        rectify(rig, "Hartley 1999")
    with pytest.raises(CamcalError, match="unknown rectification method"):
        rectify(rig, "Loop 1999", matches={})
    with pytest.raises(CamcalError, match="no rectification"):
        vertical_disparity(rig, scene_matches(rig, rng, 20))


def test_hartley_rectifies_from_matches_like_opencv():
    rng = np.random.default_rng(21)
    rig = line_rig(2, rng)
    matches = scene_matches(rig, rng, 500, sigma=SIGMA_PX)
    (x0, x1), = matches.values()
    # 15 % gross outliers that RANSAC must reject
    bad = rng.choice(len(x0), len(x0) * 15 // 100, replace=False)
    x1 = x1.copy()
    x1[bad] += rng.uniform(-80, 80, (len(bad), 2))
    result = rectify_Hartley1999(rig, {("cam0", "cam1"): (x0, x1)})
    inliers = np.setdiff1d(np.arange(len(x0)), bad)
    assert abs(result.n_inliers - len(inliers)) <= 0.02 * len(x0)
    held_out = scene_matches(rig, rng, 300)
    ours = all_rms(vertical_disparity(result.rig, held_out))
    # peer: OpenCV's uncalibrated rectification (also Hartley's) on the same undistorted inliers
    u0 = rig.cameras[0].distortion.undistort(x0[inliers], rig.cameras[0].K)
    u1 = rig.cameras[1].distortion.undistort(x1[inliers], rig.cameras[1].K)
    F, _ = cv2.findFundamentalMat(u0, u1, cv2.FM_8POINT)
    ok, H0, H1 = cv2.stereoRectifyUncalibrated(u0, u1, F, SIZE)
    assert ok
    (h0, h1), = held_out.values()
    y0 = cv2.perspectiveTransform(rig.cameras[0].distortion.undistort(h0, rig.cameras[0].K)[None], H0)[0, :, 1]
    y1 = cv2.perspectiveTransform(rig.cameras[1].distortion.undistort(h1, rig.cameras[1].K)[None], H1)[0, :, 1]
    peer = math.sqrt(np.mean((y0 - y1) ** 2))
    assert ours < 0.3 and ours <= 1.5 * peer + 0.05
    item = result.deformation
    assert all(abs(d.orthogonality_deg - 90.0) < 10.0 for d in item)


def test_hartley_refuses_an_epipole_inside_the_image():
    rng = np.random.default_rng(22)
    rig = line_rig(2, rng)
    forward = dataclasses.replace(rig, cameras=(rig.cameras[0], dataclasses.replace(rig.cameras[1], c=np.array([0.05, 0.02, 1.0]))))
    matches = scene_matches(forward, rng, 300)
    with pytest.raises(CamcalError, match="epipole .* inside the image"):
        rectify_Hartley1999(forward, matches)


def test_mallon_whelan_metrics_of_known_homographies():
    camera = line_rig(1 + 1, np.random.default_rng(0)).cameras[0]
    w, h = camera.image_size
    shear = math.radians(4.0)
    # a pure shear tilts the vertical midline by the shear angle
    H = np.array([[1.0, math.tan(shear), 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])
    K_rect = np.array([[1000.0, 0, 640], [0, 1000.0, 360], [0, 0, 1]])
    from camcal.model.rig import Rectification
    item = image_deformation(dataclasses.replace(camera, rectification=Rectification(H, K_rect, (w, h))))
    assert item.orthogonality_deg == pytest.approx(90.0 - 4.0, abs=1e-9)
    # an anisotropic scale (sx, sy) makes diagonals of lengths |(sx w, +-sy h)|: equal, ratio 1
    item = image_deformation(dataclasses.replace(
        camera, rectification=Rectification(np.diag([1.3, 0.8, 1.0]), K_rect, (w, h))))
    assert item.aspect_ratio == pytest.approx(1.0, abs=1e-12)
    assert item.orthogonality_deg == pytest.approx(90.0, abs=1e-9)


def test_matches_csv(tmp_path):
    path = tmp_path / "m.csv"
    path.write_text("camera_a,u_a,v_a,camera_b,u_b,v_b\nL,1,2,R,3,4.5\nL,5,6,R,7,8\n")
    matches = read_matches_csv(path)
    assert list(matches) == [("L", "R")]
    assert matches[("L", "R")][1].tolist() == [[3.0, 4.5], [7.0, 8.0]]
    path.write_text("a,b\n")
    with pytest.raises(CamcalError, match="first line"):
        read_matches_csv(path)
    path.write_text("camera_a,u_a,v_a,camera_b,u_b,v_b\nL,x,2,R,3,4\n")
    with pytest.raises(CamcalError, match="line 2"):
        read_matches_csv(path)


# -- images: one remap, corners on the same row --------------------------------------------


def render_board(camera, squares=(10, 7), square=0.12, origin=(-0.5, -0.3, 3.0), samples=3):
    """A chessboard on the plane z = origin_z, rendered by supersampled inverse mapping."""
    w, h = camera.image_size
    step = 1.0 / samples
    offsets = (np.arange(samples) + 0.5) * step - 0.5
    v, u = np.mgrid[0:h * samples, 0:w * samples]
    pixels = np.column_stack([u.ravel() * step + offsets[0], v.ravel() * step + offsets[0]])
    und = camera.distortion.undistort(pixels, camera.K)
    rays = np.column_stack([und, np.ones(len(und))]) @ np.linalg.inv(camera.K).T @ camera.R
    t = (origin[2] - camera.c[2]) / rays[:, 2]
    X = camera.c + rays * t[:, None]
    i = np.floor((X[:, 0] - origin[0]) / square)
    j = np.floor((X[:, 1] - origin[1]) / square)
    inside = (i >= 0) & (i < squares[0]) & (j >= 0) & (j < squares[1])
    value = np.where(inside, np.where((i + j) % 2 == 0, 30.0, 225.0), 128.0)
    image = value.reshape(h, samples, w, samples).mean(axis=(1, 3))
    return np.round(cv2.GaussianBlur(image, (0, 0), 0.7)).astype(np.uint8)


def test_write_puts_corresponding_corners_on_one_row(tmp_path):
    rng = np.random.default_rng(31)
    # division models undistort in closed form: rendering stays fast
    rig = line_rig(2, rng, max_angle_deg=3.0, distortions=DISTORTIONS[1:2])
    result = rectify_calibrated(rig)
    paths = {}
    for camera in rig.cameras:
        paths[camera.name] = tmp_path / f"{camera.name}.png"
        cv2.imwrite(str(paths[camera.name]), render_board(camera))
    out = tmp_path / "out"
    rig_path = tmp_path / "in.rig.json"
    rig.save(rig_path)
    code = main(["rectify", str(rig_path), "--images", *(f"{n}={p}" for n, p in paths.items()),
                 "--out", str(tmp_path / "rect.rig.json"), "--write", str(out), "--report", str(tmp_path / "rep")])
    assert code == 0
    corners = []
    for name in ("cam0", "cam1"):
        image = cv2.imread(str(out / name / f"{name}.png"), cv2.IMREAD_GRAYSCALE)
        assert image.shape == (result.image_size[1], result.image_size[0])
        found, points = cv2.findChessboardCorners(image, (9, 6))
        assert found, name
        points = cv2.cornerSubPix(image, points, (5, 5), (-1, -1),
                                  (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 50, 1e-3))
        corners.append(points.reshape(-1, 2))  # OpenCV 5 returns (N, 2), 4.x (N, 1, 2)
    # the detector's own error, on the original renders against the true corners
    X = np.array([[-0.5 + 0.12 * (1 + i), -0.3 + 0.12 * (1 + j), 3.0] for j in range(6) for i in range(9)])
    truth = [result.rig.camera(n).rectification.H for n in ("cam0", "cam1")]
    expected = []
    for H, camera in zip(truth, rig.cameras):
        mapped = np.column_stack([camera.distortion.undistort(camera.project(X), camera.K), np.ones(len(X))]) @ H.T
        expected.append(mapped[:, :2] / mapped[:, 2:])
    for found, want in zip(corners, expected):  # detected where the rectification says, in some order
        assert np.linalg.norm(found[:, None] - want[None], axis=2).min(axis=1).max() < 0.5
    assert np.abs(expected[0][:, 1] - expected[1][:, 1]).max() < 1e-6
    original_rows = [c.project(X)[:, 1] for c in rig.cameras]
    assert np.abs(original_rows[0] - original_rows[1]).max() > 5.0  # rows differed before
    # corners with the same index: the detector orders both boards alike
    rows = corners[0][:, 1] - corners[1][:, 1]
    assert np.sqrt(np.mean(rows**2)) < 0.3 and np.abs(rows).max() < 0.8
    # and the written rig carries what the library computed
    written = Rig.load(tmp_path / "rect.rig.json")
    assert np.allclose(written.camera("cam1").rectification.H, result.rig.camera("cam1").rectification.H)
    assert (tmp_path / "rep" / "rectification.json").is_file()


def test_maps_match_opencv_init_undistort_rectify_map():
    rng = np.random.default_rng(33)
    rig = line_rig(2, rng, distortions=DISTORTIONS[:1])
    small = [dataclasses.replace(c, image_size=(320, 180), K=np.diag([0.25, 0.25, 1.0]) @ c.K) for c in rig.cameras]
    small[0] = dataclasses.replace(small[0], K=np.array([[250.0, 0, 160.2], [0, 249.5, 90.1], [0, 0, 1]]))
    result = rectify_calibrated(dataclasses.replace(rig, cameras=tuple(small)))
    warper = RectifyWarper(result.rig)
    for camera in result.rig.cameras:
        p = camera.distortion.params
        D = np.array([p["k1"], p["k2"], p["p1"], p["p2"], p["k3"]])
        map_x, map_y = cv2.initUndistortRectifyMap(camera.K, D, result.R_rect @ camera.R.T, result.K_rect,
                                                   result.image_size, cv2.CV_32FC1)
        maps = warper.maps(camera.name)
        valid = (map_x > 0) & (map_x < 319) & (map_y > 0) & (map_y < 179)
        assert valid.mean() > 0.9
        assert np.abs(maps.map_x - map_x)[valid].max() < 1e-3 and np.abs(maps.map_y - map_y)[valid].max() < 1e-3


def test_warper_caches_maps_per_camera():
    rng = np.random.default_rng(32)
    result = rectify_calibrated(line_rig(2, rng))
    warper = RectifyWarper(result.rig)
    assert warper.maps("cam0") is warper.maps("cam0")
    with pytest.raises(CamcalError, match="640x360"):
        warper.warp("cam0", np.zeros((360, 640), np.uint8))


# -- CLI ------------------------------------------------------------------------------------


def test_cli_help(capsys):
    with pytest.raises(SystemExit) as info:
        main(["rectify", "--help"])
    assert info.value.code == 0 and "usage: camcal rectify" in capsys.readouterr().out


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--alpha", "1.5"], "alpha"),
        (["--method", "hartley"], "needs point matches"),
        (["--images", "nope=/nonexistent/*.png"], "no camera 'nope'"),
        (["--write", "DIR"], "--write needs --images"),
    ],
)
def test_cli_bad_input(tmp_path, capsys, extra, message):
    rig_path = tmp_path / "in.rig.json"
    line_rig(2, np.random.default_rng(1)).save(rig_path)
    out = tmp_path / "rect.rig.json"
    extra = [str(tmp_path / "w") if a == "DIR" else a for a in extra]
    assert main(["rectify", str(rig_path), "--out", str(out), *extra]) == 2
    assert message in capsys.readouterr().err
    assert not out.exists() and not (tmp_path / "w").exists()


def test_cli_missing_rig(tmp_path, capsys):
    out = tmp_path / "rect.rig.json"
    assert main(["rectify", str(tmp_path / "none.rig.json"), "--out", str(out)]) == 2
    assert "camcal: error:" in capsys.readouterr().err and not out.exists()


def test_cli_hartley_from_matches_file(tmp_path, capsys):
    rng = np.random.default_rng(41)
    rig = line_rig(2, rng)
    (x0, x1), = scene_matches(rig, rng, 200, sigma=SIGMA_PX).values()
    lines = ["camera_a,u_a,v_a,camera_b,u_b,v_b"] + [f"cam0,{a[0]:.17g},{a[1]:.17g},cam1,{b[0]:.17g},{b[1]:.17g}" for a, b in zip(x0, x1)]
    (tmp_path / "m.csv").write_text("\n".join(lines) + "\n")
    rig.save(tmp_path / "in.rig.json")
    code = main(["rectify", str(tmp_path / "in.rig.json"), "--method", "hartley", "--matches",
                 str(tmp_path / "m.csv"), "--out", str(tmp_path / "r.rig.json")])
    assert code == 0
    printed = capsys.readouterr().out
    assert "Hartley 1999" in printed and "vertical disparity cam0-cam1" in printed
    rectified = Rig.load(tmp_path / "r.rig.json")
    held_out = scene_matches(rig, rng, 200)
    assert all_rms(vertical_disparity(rectified, held_out)) < 0.3


# -- real stereo pairs: camcal vs cv2.stereoRectify on the same OpenCV calibration ----------------


BOARD = (9, 6)


@pytest.fixture(scope="module")
def stereo_detections(shared_data):
    folder = shared_data / "stereo_chessboard"
    criteria = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 40, 1e-3)
    pairs = []
    for index in range(1, 26):
        found = []
        for side in ("left", "right"):
            image = cv2.imread(str(folder / f"{side}{index:02d}.jpg"), cv2.IMREAD_GRAYSCALE)
            ok, corners = cv2.findChessboardCorners(image, BOARD, flags=cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE)
            if not ok:
                break
            found.append(cv2.cornerSubPix(image, corners, (11, 11), (-1, -1), criteria).reshape(-1, 2).astype(np.float64))
        if len(found) == 2:
            pairs.append((index, found[0], found[1]))
    size = (image.shape[1], image.shape[0])
    return folder, size, pairs


@pytest.fixture(scope="module")
def stereo_calibration(stereo_detections):
    folder, size, pairs = stereo_detections
    assert len(pairs) >= 22, f"board found in only {len(pairs)} of 25 pairs"
    train, test = pairs[:20], pairs[20:25]
    board = np.zeros((BOARD[0] * BOARD[1], 3), np.float32)
    board[:, :2] = np.mgrid[0:BOARD[0], 0:BOARD[1]].T.reshape(-1, 2)
    objects = [board] * len(train)
    left = [p[1].astype(np.float32) for p in train]
    right = [p[2].astype(np.float32) for p in train]
    _, K1, D1, _, _ = cv2.calibrateCamera(objects, left, size, None, None)
    _, K2, D2, _, _ = cv2.calibrateCamera(objects, right, size, None, None)
    rms, K1, D1, K2, D2, R, T, _, _ = cv2.stereoCalibrate(
        objects, left, right, K1, D1, K2, D2, size, flags=cv2.CALIB_FIX_INTRINSIC,
        criteria=(cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-9))
    T = T.ravel()

    def camera(name, K, D, R_, c):
        k1, k2, p1, p2, k3 = D.ravel()[:5]
        return Camera(name, size, K, Distortion("opencv", {"k1": k1, "k2": k2, "p1": p1, "p2": p2, "k3": k3}), R_, c)

    R = Rotation.from_matrix(R).as_matrix()  # exactly orthonormal for the rig's check
    rig = Rig((camera("left", K1, D1, np.eye(3), np.zeros(3)), camera("right", K2, D2, R, -R.T @ T)), units="squares")
    return rig, (K1, D1, K2, D2, R, T, size), train, test, rms


def test_real_pairs_rectify_at_least_as_well_as_opencv(stereo_calibration):
    rig, (K1, D1, K2, D2, R, T, size), train, test, rms = stereo_calibration
    assert rms < 1.0
    held_out = {("left", "right"): (np.vstack([p[1] for p in test]), np.vstack([p[2] for p in test]))}
    ours = rectify_calibrated(rig, alpha=0.0)
    (disparity,) = vertical_disparity(ours.rig, held_out)
    # OpenCV 5 reads a 1-D T as a 1x3 row (true 1-D Mats) and stereoRectify then fails: give 3x1
    R1, R2, P1, P2, *_ = cv2.stereoRectify(K1, D1, K2, D2, size, R, T.reshape(3, 1), alpha=0.0)
    y1 = cv2.undistortPoints(held_out[("left", "right")][0][:, None], K1, D1, R=R1, P=P1)[:, 0, 1]
    y2 = cv2.undistortPoints(held_out[("left", "right")][1][:, None], K2, D2, R=R2, P=P2)[:, 0, 1]
    peer_rms = float(np.sqrt(np.mean((y1 - y2) ** 2)))
    print(f"held-out vertical disparity: camcal {disparity.rms_px:.4f} px (f {ours.K_rect[0, 0]:.1f}), "
          f"OpenCV {peer_rms:.4f} px (f {P1[0, 0]:.1f})")
    assert disparity.n == 5 * BOARD[0] * BOARD[1]
    assert disparity.rms_px <= peer_rms
    # in angle (pixels over focal length) the two rectifications agree: the gap is OpenCV's zoom
    assert disparity.rms_px / ours.K_rect[0, 0] == pytest.approx(peer_rms / P1[0, 0], rel=0.02)
    # the joint refinement on the 20 training pairs' corners, checked on the 5 others
    training = {("left", "right"): (np.vstack([p[1] for p in train]), np.vstack([p[2] for p in train]))}
    refined = rectify_Nozick2011(rig, training)
    (after,) = vertical_disparity(refined.rig, held_out)
    print(f"after the joint refinement: {after.rms_px:.4f} px")
    assert after.rms_px <= disparity.rms_px * 1.05


def test_sift_matches_on_real_pairs_agree_with_the_calibration(stereo_calibration, shared_data):
    rig, *_ = stereo_calibration
    folder = shared_data / "stereo_chessboard"
    matches = match_image_files(rig, {"left": folder / "left21.jpg", "right": folder / "right21.jpg"})
    rectified = rectify_calibrated(rig).rig
    ((xa, xb),) = matches.values()
    rows = [vertical_disparity(rectified, {("left", "right"): (xa[i:i + 1], xb[i:i + 1])})[0].max_px
            for i in range(len(xa))]
    print(f"SIFT on pair 21: {len(rows)} matches, |vertical disparity| median {np.median(rows):.3f} px, "
          f"share under 1 px {np.mean(np.array(rows) < 1.0):.0%}")
    # the board dominates the scene (near-planar: F is weakly constrained), so some wrong matches
    # pass the epipolar filter; the majority are true and sit on their rows
    assert len(rows) >= 20 and np.median(rows) < 0.5
