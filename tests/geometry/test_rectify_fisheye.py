"""Rectification of Kannala-Brandt (OpenCV fisheye) rigs: rows against the geometry the test builds,
cv2.fisheye.stereoRectify / initUndistortRectifyMap as the peer, the field-of-view cap, the CLI."""

import dataclasses
import math
import subprocess
import sys

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from camcal.base.errors import CamcalError
from camcal.model.distortion import Distortion
from camcal.geometry.rectify import RectifyWarper, rectify_calibrated, rectify_Nozick2011, vertical_disparity
from camcal.geometry.remap import build_maps_reference
from camcal.model.rig import Rig
from camcal.synthetic import example_stereo_rig, procedural_texture, render_planes

#: two fisheye lenses (OpenCV fisheye coefficients), one-to-one up to 121 and 118 degrees off the axis
LENSES = ({"k1": 0.03, "k2": -0.01, "k3": 0.004, "k4": -0.0008}, {"k1": 0.025, "k2": -0.012, "k3": 0.005, "k4": -0.001})


def fisheye_pair(f=330.0, image_size=(960, 720)):
    """A stereo rig (principal points off-centre, focal 1 % apart, right camera turned by ~2 deg) with
    fisheye lenses: at f = 330 px on 960 x 720 the frame's corners see 98 degrees off the axis."""
    left, right = example_stereo_rig(image_size=image_size, f=f)
    return Rig(tuple(dataclasses.replace(camera, distortion=Distortion("kannala-brandt", lens))
                     for camera, lens in zip((left, right), LENSES)), units="m")


def coefficients(camera):
    return np.array([camera.distortion.params[k] for k in ("k1", "k2", "k3", "k4")])


def opencv_fisheye_rectify(left, right):
    """cv2.fisheye.stereoRectify on the rig: R1, R2, P1, P2 (x_right = R x_left + T)."""
    R = right.R @ left.R.T
    T = right.R @ (left.c - right.c)
    R1, R2, P1, P2, _ = cv2.fisheye.stereoRectify(left.K, coefficients(left), right.K, coefficients(right),
                                                  left.image_size, R, T, cv2.CALIB_ZERO_DISPARITY)
    return R1, R2, P1, P2


def points_in_rectified_view(result, rng, n=3000, half_angle_deg=55.0):
    """World points 2-10 m from the left camera whose rays lie within ``half_angle_deg`` of the
    rectified viewing direction (inside the rectified field of view)."""
    theta = np.radians(half_angle_deg) * np.sqrt(rng.uniform(0.0, 1.0, n))
    phi = rng.uniform(0.0, 2 * np.pi, n)
    rays = np.column_stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)])
    return result.rig.cameras[0].c + (rays * rng.uniform(2.0, 10.0, n)[:, None]) @ result.R_rect


def rectified_pixels(camera, points_px):
    """Rectified pixels of distorted pixels: ``H K r`` with ``r`` the pixel's ray."""
    mapped = camera.distortion.rays_from_pixels(points_px, camera.K) @ camera.K.T @ camera.rectification.H.T
    return mapped[:, :2] / mapped[:, 2:]


@pytest.mark.parametrize("f, alpha", [(330.0, 0.0), (330.0, 1.0), (250.0, 0.5)])
def test_fisheye_rows_agree_exactly_and_as_cv2_fisheye_stereo_rectify(f, alpha):
    """Same 3D point, same row: to 1e-6 px against the rectified cameras K_rect R_rect [I | -c], and
    cv2.fisheye's rectification of the same pixels to 1e-6 px (same rotations; f = 250 px also has frame
    corners beyond the lens model's range, as a circular fisheye does)."""
    rig = fisheye_pair(f)
    result = rectify_calibrated(rig, alpha=alpha)
    print(result.summary())
    R1, R2, P1, P2 = opencv_fisheye_rectify(*rig.cameras)
    X = points_in_rectified_view(result, np.random.default_rng(0))
    rows = {}
    for camera, R_cv, P in zip(result.rig.cameras, (R1, R2), (P1, P2)):
        # the rotation: cv2.fisheye's R1, R2 are R_rect R_i^T (the convention of cv2.stereoRectify too)
        angle = math.degrees(Rotation.from_matrix(R_cv @ camera.R @ result.R_rect.T).magnitude())
        print(f"{camera.name}: rotation vs cv2.fisheye.stereoRectify {angle:.2e} deg")
        assert angle < 1e-9
        distorted = camera.project(X)
        ours = rectified_pixels(camera, distorted)
        truth = (X - camera.c) @ result.R_rect.T @ result.K_rect.T
        assert np.abs(ours - truth[:, :2] / truth[:, 2:]).max() < 1e-6
        # cv2.fisheye on the same pixels, in its own P; then on our K_rect (a convention: cv2 picks its focal
        # by balance / fov_scale, camcal keeps the mean focal)
        theirs = cv2.fisheye.undistortPoints(distorted[:, None, :], camera.K, coefficients(camera), R=R_cv, P=P,
                                             criteria=(cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-14))[:, 0]
        theirs_in_ours = (theirs - P[:2, 2]) / P[0, 0] * result.K_rect[0, 0] + result.K_rect[:2, 2]
        difference = np.abs(theirs_in_ours - ours).max()
        print(f"{camera.name}: rectified pixels vs cv2.fisheye.undistortPoints(R{camera.name == 'right' and 2 or 1}, P) "
              f"{difference:.1e} px (cv2 focal {P[0, 0]:.1f} px, camcal {result.K_rect[0, 0]:.1f} px)")
        assert difference < 1e-6
        rows[camera.name] = ours[:, 1]
    assert np.abs(rows["left"] - rows["right"]).max() < 1e-6
    (disparity,) = vertical_disparity(result.rig, {("left", "right"): tuple(c.project(X) for c in result.rig.cameras)})
    assert disparity.n == len(X) and disparity.max_px < 1e-6
    for item in result.deformation:
        assert item.valid_fraction > 0.999 if alpha == 0.0 else item.valid_fraction > 0.5


def test_fisheye_maps_sample_the_ray_of_each_rectified_pixel():
    """The remap maps (built by cv2.fisheye.initUndistortRectifyMap) send every rectified pixel to the
    distorted pixel of its own ray, to float32 precision; cv2.fisheye's maps for R1 and our K_rect agree."""
    rig = fisheye_pair()
    result = rectify_calibrated(rig, alpha=1.0)
    width, height = result.image_size
    u, v = np.meshgrid(np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64))
    pixels = np.column_stack([u.ravel(), v.ravel(), np.ones(u.size)])
    warper = RectifyWarper(result.rig)
    for camera, R_cv in zip(result.rig.cameras, opencv_fisheye_rectify(*rig.cameras)[:2]):
        rays = pixels @ np.linalg.inv(result.K_rect).T @ result.R_rect @ camera.R.T  # rectified pixel -> camera ray
        expected = camera.distortion.project_rays(rays, camera.K)
        maps = warper.maps(camera.name)
        got = np.column_stack([maps.map_x.ravel(), maps.map_y.ravel()])
        valid = np.all((expected > -0.5) & (expected < np.array(camera.image_size) - 0.5), axis=1)
        assert valid.mean() > 0.5 and np.all(got[valid] >= 0)
        error = np.abs(got[valid] - expected[valid]).max()
        reference = build_maps_reference(camera, camera.rectification.H, result.image_size)
        error_reference = max(np.abs(reference.map_x - maps.map_x)[maps.map_x >= 0].max(),
                              np.abs(reference.map_y - maps.map_y)[maps.map_y >= 0].max())
        mx, my = cv2.fisheye.initUndistortRectifyMap(camera.K, coefficients(camera), R_cv, result.K_rect,
                                                     result.image_size, cv2.CV_32FC1)
        error_cv2 = max(np.abs(mx.ravel() - got[:, 0])[valid].max(), np.abs(my.ravel() - got[:, 1])[valid].max())
        print(f"{camera.name}: maps vs rays {error:.1e} px, vs the float64 reference {error_reference:.1e} px, "
              f"vs cv2.fisheye maps for R_cv {error_cv2:.1e} px")
        assert error < 2e-3 and error_reference < 2e-3 and error_cv2 < 2e-3


def test_field_of_view_cap_bounds_the_rectified_image():
    """A pinhole image cannot hold rays at 90 degrees: the frame holds at most max_fov / 2 about the
    rectified axis (default 120 degrees with a fisheye, as `camcal undistort`), every side reaching it."""
    rig = fisheye_pair()
    for fov, kwargs in ((120.0, {}), (90.0, {"max_fov_deg": 90.0})):
        result = rectify_calibrated(rig, alpha=1.0, **kwargs)
        assert result.max_fov_deg == pytest.approx(fov) and f"field of view capped at {fov:g} deg" in result.summary()
        assert result.to_report()["max_fov_deg"] == pytest.approx(fov)
        reach = result.K_rect[0, 0] * math.tan(math.radians(fov / 2))
        width, height = result.image_size
        assert width == pytest.approx(2 * reach, abs=2) and height == pytest.approx(2 * reach, abs=2)
        assert result.K_rect[0, 2] == pytest.approx(reach, abs=1) and result.K_rect[1, 2] == pytest.approx(reach, abs=1)
    # so wide that the other camera (88.9 deg off the left camera's axis) is in view: refused with the
    # reason, as is a cap out of (0, 180)
    with pytest.raises(CamcalError, match="line of centres points into camera 'left'"):
        rectify_calibrated(fisheye_pair(250.0), max_fov_deg=179.0)
    with pytest.raises(CamcalError, match="between 0 and 180 degrees, got 180"):
        rectify_calibrated(rig, max_fov_deg=180)


def test_fisheye_looking_along_the_baseline_is_refused_and_a_side_epipole_is_not():
    left, right = fisheye_pair(250.0).cameras
    # right camera 1 m ahead of the left along its axis: the epipole is at the centre of both images
    ahead = dataclasses.replace(right, R=np.eye(3), c=np.array([0.0, 0.0, 1.0]))
    with pytest.raises(CamcalError, match="line of centres points into camera"):
        rectify_calibrated(Rig((left, ahead)))
    # side by side, the baseline direction is 90 deg off the axis: inside this fisheye's frame (it sees
    # 121 deg) but outside the 120 deg rectified field of view
    assert np.all(np.isfinite(left.distortion.project_rays(np.array([[1.0, 0.0, 0.0]]), left.K)))
    assert rectify_calibrated(Rig((left, right))).image_size[0] > 0


def test_three_fisheye_cameras_on_a_line_and_the_nozick_refinement():
    """N views: rows agree to 1e-6 px for every pair on points inside the rectified field of view;
    Nozick 2011 started on an exact calibration with exact matches stays there, with wide matches (up to
    ~110 deg off the axis, some behind the rectified plane) among its input: those behind are left out
    of the refinement and of the disparity figures."""
    rng = np.random.default_rng(4)
    base = fisheye_pair()
    cameras = []
    for i in range(3):
        turn = Rotation.from_rotvec(rng.normal(0.0, math.radians(2.0), 3)).as_matrix()
        template = base.cameras[i % 2]
        cameras.append(dataclasses.replace(template, name=f"cam{i}", R=turn, c=np.array([0.3 * i, 0.0, 0.0])))
    rig = Rig(tuple(cameras), units="m")
    calibrated = rectify_calibrated(rig)
    in_view = points_in_rectified_view(calibrated, rng)
    wide = np.column_stack([rng.uniform(-30, 30, 300), rng.uniform(-30, 30, 300), rng.uniform(-1.0, 3.0, 300)])

    def matches_of(X):
        out = {}
        for a in range(3):
            for b in range(a + 1, 3):
                xa, xb = cameras[a].project(X), cameras[b].project(X)
                seen = np.all(np.isfinite(xa) & np.isfinite(xb), axis=1)
                out[(f"cam{a}", f"cam{b}")] = (xa[seen], xb[seen])
        return out

    inside, outside = matches_of(in_view), matches_of(wide)
    everything = {key: tuple(np.vstack([inside[key][k], outside[key][k]]) for k in range(2)) for key in inside}
    for result in (calibrated, rectify_Nozick2011(rig, everything)):
        disparity = vertical_disparity(result.rig, inside)
        print(result.method, [(p.first, p.second, p.n, p.max_px) for p in disparity])
        assert len(disparity) == 3 and all(p.n == len(in_view) for p in disparity)
        assert max(p.max_px for p in disparity) < 1e-6
        for pair in vertical_disparity(result.rig, outside):
            behind = np.zeros(len(outside[(pair.first, pair.second)][0]), bool)
            for name, x in zip((pair.first, pair.second), outside[(pair.first, pair.second)]):
                camera = rig.camera(name)
                behind |= camera.distortion.rays_from_pixels(x, camera.K) @ camera.R @ result.R_rect[2] <= 0
            assert behind.any() and pair.n == len(behind) - behind.sum()


def test_nozick_refinement_corrects_a_fisheye_rig_on_held_out_matches():
    """Rotations 0.15 deg off: Nozick 2011 on noisy matches (0.2 px) brings the vertical disparity of
    other matches down to the noise floor, which the true calibration measures on the same matches."""
    rng = np.random.default_rng(5)
    rig = fisheye_pair()
    exact = rectify_calibrated(rig)

    def noisy_matches(n):
        X = points_in_rectified_view(exact, rng, n)
        return {("left", "right"): tuple(c.project(X) + rng.normal(0.0, 0.2, (n, 2)) for c in rig.cameras)}

    train, held_out = noisy_matches(400), noisy_matches(400)
    turned = []
    for camera in rig.cameras:
        axis = rng.normal(size=3)
        turned.append(dataclasses.replace(camera, R=Rotation.from_rotvec(
            axis / np.linalg.norm(axis) * math.radians(0.15)).as_matrix() @ camera.R))
    off = Rig(tuple(turned), units="m")
    (floor,), (before,), (after,) = (vertical_disparity(result.rig, held_out) for result in
                                     (exact, rectify_calibrated(off), rectify_Nozick2011(off, train)))
    print(f"held-out vertical disparity RMS: true calibration {floor.rms_px:.3f} px, off by 0.15 deg "
          f"{before.rms_px:.3f} px, refined {after.rms_px:.3f} px")
    assert before.rms_px > 1.5 * floor.rms_px and after.rms_px < 1.05 * floor.rms_px


def render_fisheye_pair(root, size=(320, 240), f=110.0):
    """A small fisheye stereo pair rendered by ray casting textured planes, and its rig."""
    rig = fisheye_pair(f, size)
    rng = np.random.default_rng(2)
    planes = ((np.array([-6.0, -5.0, 4.0]), np.array([12.0, 0.0, 0.0]), np.array([0.0, 10.0, 0.0])),
              (np.array([-1.2, -0.8, 2.0]), np.array([1.5, 0.0, -0.3]), np.array([0.0, 1.5, 0.0])))
    textures = tuple(procedural_texture(rng, 512) for _ in planes)
    for camera in rig.cameras:
        (root / camera.name).mkdir(parents=True)
        cv2.imwrite(str(root / camera.name / "0000.png"), render_planes(camera, planes, textures))
    return rig, rig.save(root / "fisheye.rig.json")


@pytest.mark.parametrize("options", [[], ["--refine"], ["--method", "hartley"]])
def test_cli_rectifies_a_rendered_fisheye_pair_like_cv2_fisheye(tmp_path, options):
    """``camcal rectify`` on a fisheye pair: the calibrated images equal cv2.fisheye's (same maps, one
    remap each); with the Nozick refinement or Hartley 1999 on SIFT matches too, SIFT matches between the
    written images lie on one row."""
    rig, rig_path = render_fisheye_pair(tmp_path)
    out = tmp_path / "rect.rig.json"
    run = subprocess.run([sys.executable, "-m", "camcal", "rectify", str(rig_path), "--images",
                          f"left={tmp_path}/left/*.png", f"right={tmp_path}/right/*.png", "--write",
                          str(tmp_path / "rect"), "--out", str(out), *options], capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    print(run.stdout)
    rectified = Rig.load(out)
    R1, R2, *_ = opencv_fisheye_rectify(*rig.cameras)
    images = {}
    for camera, R_cv in zip(rectified.cameras, (R1, R2)):
        rect = camera.rectification
        ours = cv2.imread(str(tmp_path / "rect" / camera.name / "0000.png"), cv2.IMREAD_GRAYSCALE)
        assert ours.shape == (rect.image_size[1], rect.image_size[0])
        images[camera.name] = ours
        if options:
            continue
        # the peer: cv2.fisheye's maps for the same rotation and rectified camera, one cv2.remap
        mx, my = cv2.fisheye.initUndistortRectifyMap(camera.K, coefficients(camera), R_cv, rect.K_rect,
                                                     rect.image_size, cv2.CV_32FC1)
        source = cv2.imread(str(tmp_path / camera.name / "0000.png"), cv2.IMREAD_GRAYSCALE)
        theirs = cv2.remap(source, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        assert np.abs(ours.astype(int) - theirs.astype(int)).max() <= 1
    # the rectified images themselves: SIFT matches between them lie on one row
    sift = cv2.SIFT_create()
    (kp_a, desc_a), (kp_b, desc_b) = (sift.detectAndCompute(images[name], None) for name in ("left", "right"))
    pairs = [m for m, n in cv2.BFMatcher().knnMatch(desc_a, desc_b, k=2) if m.distance < 0.7 * n.distance]
    dy = np.array([kp_a[m.queryIdx].pt[1] - kp_b[m.trainIdx].pt[1] for m in pairs])
    print(f"{len(dy)} SIFT matches on the rectified pair: median |dy| {np.median(np.abs(dy)):.3f} px")
    assert len(dy) > 30 and np.median(np.abs(dy)) < 0.3


@pytest.mark.parametrize("extra, message", [(["--max-fov", "200"], "between 0 and 180 degrees, got 200"),
                                            (["--max-fov", "179"], "line of centres points into camera 'left'")])
def test_cli_fisheye_bad_input_is_one_line(tmp_path, extra, message):
    rig_path = fisheye_pair(250.0).save(tmp_path / "fisheye.rig.json")
    out = tmp_path / "rect.rig.json"
    run = subprocess.run([sys.executable, "-m", "camcal", "rectify", str(rig_path), "--out", str(out), *extra],
                         capture_output=True, text=True)
    assert run.returncode == 2 and message in run.stderr and len(run.stderr.strip().splitlines()) == 1
    assert not out.exists()
