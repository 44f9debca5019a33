"""A kannala-brandt camera in Blender: Cycles' fisheye-polynomial camera, checked by projection.

The pure part (addon.fisheye.blender_fisheye, fisheye_polynomial_ray: Cycles'
formula) is compared with camcal's projection on every pixel of the frame;
a slow test renders emissive spheres with Cycles and compares their
centroids with the centroids camcal predicts (the area centroid of each
sphere's image, whose outline is the projection through camcal's model of
the cone the sphere subtends, so the fisheye's stretching of a sphere's
image is not counted as an error).
"""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from addon_helpers import camera_dict, write_rig
from addon_helpers import addon, bpy  # noqa: F401  (fixtures)
from camcal.model.distortion import Distortion

#: the render test's lens: 240 x 180, about 170 degrees across the diagonal
SIZE = (240, 180)
K = np.array([[100.0, 0.0, 123.3], [0.0, 99.2, 86.6], [0.0, 0.0, 1.0]])
PARAMS = {"k1": 0.021, "k2": -0.0042, "k3": 0.0013, "k4": -0.00021}


def formula_error_px(addon, K, size, params, step=2.0):
    """Largest distance between a pixel and camcal's projection of the ray Cycles traces through it."""
    f = addon.fisheye.blender_fisheye(K.tolist(), size, params)
    u, v = np.meshgrid(np.arange(0.0, size[0], step), np.arange(0.0, size[1], step))
    pixels = np.column_stack([u.ravel(), v.ravel()])
    rays = np.array([addon.fisheye.fisheye_polynomial_ray(f, p) for p in pixels], dtype=float)
    back = Distortion("kannala-brandt", params).project_rays(rays, K)
    return f, float(np.max(np.linalg.norm(back - pixels, axis=1)))


@pytest.mark.parametrize(
    "K, size, params, bound",
    [
        (K, SIZE, PARAMS, 0.01),
        # equidistant (all k = 0): the quartic is exact
        (np.array([[402.0, 0.0, 646.3], [0.0, 400.5, 473.1], [0.0, 0.0, 1.0]]), (1280, 960),
         dict.fromkeys(("k1", "k2", "k3", "k4"), 0.0), 1e-6),
        # portrait, fy > fx (pixel aspect), principal point off centre
        (np.array([[150.0, 0.0, 93.1], [0.0, 151.5, 125.4], [0.0, 0.0, 1.0]]), (180, 240),
         {"k1": 0.012, "k2": -0.003, "k3": 0.0004, "k4": -0.00003}, 0.01),
    ],
    ids=["render-lens", "equidistant", "portrait-aspect"],
)
def test_cycles_formula_projects_like_camcal(addon, K, size, params, bound):
    f, error = formula_error_px(addon, K, size, params)
    print(f"{size} {params}: Cycles formula vs camcal max {error:.2e} px (fit reports {f.fit_max_px:.2e} px)")
    assert error < bound
    # the reported fit residual is the one measured on the frame (radial samples vs a pixel grid)
    assert error <= f.fit_max_px * 1.05 + 1e-9


def test_wide_lens_fit_residual_is_reported_honestly(addon):
    """A 220-degree lens is beyond a quartic: the residual says so, and it is the true one."""
    K_wide = np.array([[402.0, 0.0, 646.3], [0.0, 400.5, 473.1], [0.0, 0.0, 1.0]])
    params = {"k1": 0.032, "k2": -0.011, "k3": 0.0036, "k4": -0.00052}
    f, error = formula_error_px(addon, K_wide, (1280, 960), params, step=8.0)
    print(f"wide lens: fit max {f.fit_max_px:.3f} px, rms {f.fit_rms_px:.3f} px; grid max {error:.3f} px")
    assert f.fit_max_px > 0.1
    assert error == pytest.approx(f.fit_max_px, rel=0.1)


def test_rig_file_accepts_kannala_brandt_and_rejects_missing_terms(addon, tmp_path):
    good = camera_dict("fish", SIZE, K, distortion={"model": "kannala-brandt", "params": PARAMS})
    rig = addon.rigfile.load_rig(str(write_rig(tmp_path / "ok.rig.json", [good])))
    assert rig.cameras[0].distortion.model == "kannala-brandt"
    bad = camera_dict("fish", SIZE, K, distortion={"model": "kannala-brandt", "params": {"k1": 0.1}})
    with pytest.raises(addon.rigfile.RigFileError, match="needs 'k2'"):
        addon.rigfile.parse_rig({"format": "camcal.rig", "version": 1, "units": "m", "cameras": [bad], "frames": [],
                                 "points": None})


def test_importer_builds_a_fisheye_polynomial_camera(bpy, addon, tmp_path):
    path = write_rig(tmp_path / "f.rig.json",
                     [camera_dict("fish", SIZE, K, distortion={"model": "kannala-brandt", "params": PARAMS})])
    result = addon.import_rig(bpy.context.scene, str(path))
    data = result.cameras["fish"].data
    f = addon.fisheye.blender_fisheye(K.tolist(), SIZE, PARAMS)
    assert data.type == "PANO" and data.panorama_type == "FISHEYE_LENS_POLYNOMIAL"
    for n in range(5):
        assert getattr(data, f"fisheye_polynomial_k{n}") == pytest.approx(f.polynomial[n], rel=1e-6, abs=1e-12)
    assert (data.shift_x, data.shift_y) == pytest.approx((f.shift_x, f.shift_y), abs=1e-7)
    assert data.fisheye_fov >= f.fov
    assert not result.clips  # the lens lives in the camera, not in a MovieClip
    assert any("fisheye-polynomial" in w for w in result.warnings)


def _expected_centroids(rays_centre, radius, distance, lens, K=K, n_edge=2000):
    """Area centroid of each sphere's image as camcal's lens draws it.

    A sphere of radius ``radius`` at ``distance`` along a unit ray is seen as the cone of half-angle
    ``asin(radius / distance)`` about that ray; its image is the region inside the projection of the
    cone's edge (``n_edge`` rays), whose centroid the shoelace formula gives. (The projection of the
    sphere's centre is not the centroid of its image under a fisheye: the image is stretched.)
    """
    alpha = np.arcsin(radius / distance)
    phi = np.linspace(0.0, 2.0 * np.pi, n_edge, endpoint=False)
    out = []
    for axis in rays_centre:
        a = np.cross(axis, [0.0, 0.0, 1.0] if abs(axis[2]) < 0.9 else [1.0, 0.0, 0.0])
        a /= np.linalg.norm(a)
        b = np.cross(axis, a)
        edge = np.cos(alpha) * axis + np.sin(alpha) * (np.cos(phi)[:, None] * a + np.sin(phi)[:, None] * b)
        x, y = lens.project_rays(edge, K).T
        cross = x * np.roll(y, -1) - np.roll(x, -1) * y
        area = cross.sum() / 2.0
        out.append((((x + np.roll(x, -1)) * cross).sum() / (6.0 * area),
                    ((y + np.roll(y, -1)) * cross).sum() / (6.0 * area)))
    return np.array(out)


RENDER_CASES = {
    # landscape, fx != fy (pixel aspect), principal point off centre, camera at the origin
    "landscape": (SIZE, K, PARAMS, np.eye(3), np.zeros(3), (8, 6)),
    # portrait (vertical fit), fy > fx, a turned and moved camera
    "portrait-posed": ((180, 240), np.array([[118.0, 0.0, 93.1], [0.0, 119.5, 125.4], [0.0, 0.0, 1.0]]),
                       {"k1": 0.012, "k2": -0.003, "k3": 0.0004, "k4": -0.00003},
                       Rotation.from_euler("xyz", [12.0, -25.0, 8.0], degrees=True).as_matrix(),
                       np.array([0.3, -0.2, 0.5]), (6, 8)),
}


@pytest.mark.slow
@pytest.mark.parametrize("case", RENDER_CASES)
def test_cycles_render_of_the_fisheye_matches_camcal(bpy, addon, tmp_path, case):
    from test_addon_render import _emissive_spheres, _render  # the existing render method

    size, K_case, params, R, c, (nx, ny) = RENDER_CASES[case]
    lens = Distortion("kannala-brandt", params)
    # directions on a grid over the frame (apart enough that windows hold one sphere each), to the edges
    u, v = np.meshgrid(np.linspace(11, size[0] - 12, nx), np.linspace(11, size[1] - 12, ny))
    rays = lens.rays_from_pixels(np.column_stack([u.ravel(), v.ravel()]), K_case)
    distance, radius = 4.0, 0.1
    scene = bpy.context.scene
    _emissive_spheres(bpy, scene, (rays * distance) @ R + c, np.full(len(rays), radius))  # world = R^T x_cam + c
    path = write_rig(tmp_path / "f.rig.json", [camera_dict("fish", size, K_case, R, c,
                                                           distortion={"model": "kannala-brandt", "params": params})])
    addon.import_rig(scene, str(path))
    image = _render(bpy, scene, tmp_path / "f.exr", samples=1024)
    expected = _expected_centroids(rays, radius, distance, lens, K_case)
    window = 7
    measured = []
    for x, y in expected:
        x0, y0 = int(round(x)), int(round(y))
        ys, xs = np.mgrid[y0 - window:y0 + window + 1, x0 - window:x0 + window + 1]
        w = image[ys, xs]
        measured.append(((w * xs).sum() / w.sum(), (w * ys).sum() / w.sum()))
    error = np.hypot(*(np.array(measured) - expected).T)
    angles = np.degrees(np.arccos(rays[:, 2]))
    f = addon.fisheye.blender_fisheye(K_case.tolist(), size, params)
    print(f"Cycles fisheye render vs camcal ({case}): centroid error max {error.max():.4f} px, "
          f"mean {error.mean():.4f} px, median {np.median(error):.4f} px over {len(error)} spheres up to "
          f"{angles.max():.0f} deg off axis; quartic fit residual max {f.fit_max_px:.4f} px")
    # measured on bpy 5.2.3 at 1024 samples: max 0.0066 / 0.0087 px, median 0.0024 px (at 256 samples
    # 0.0094 / 0.0123 and 0.004: Cycles' sampling noise, not the model, which the formula test above
    # holds to < 0.002 px)
    assert np.median(error) < 0.004
    assert error.max() < 0.01


def test_cli_blender_import_writes_the_fisheye_camera(addon, tmp_path, capsys):
    """The headless ``camcal blender import`` path carries the fisheye camera into the .blend."""
    import subprocess
    import sys

    from camcal.cli import main

    pytest.importorskip("bpy")
    rig = write_rig(tmp_path / "f.rig.json",
                    [camera_dict("fish", SIZE, K, distortion={"model": "kannala-brandt", "params": PARAMS})])
    out = tmp_path / "f.blend"
    assert main(["blender", "import", str(rig), "--blend", str(out)]) == 0
    assert "fisheye-polynomial" in capsys.readouterr().out
    script = (
        "import bpy, sys; bpy.ops.wm.open_mainfile(filepath=sys.argv[1]); "
        "c = [o for o in bpy.data.objects if o.type == 'CAMERA'][0].data; "
        "print(c.type, c.panorama_type, repr(c.fisheye_polynomial_k1), repr(c.shift_x))"
    )
    proc = subprocess.run([sys.executable, "-c", script, str(out)], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    kind, panorama, k1, shift_x = proc.stdout.split()[-4:]
    f = addon.fisheye.blender_fisheye(K.tolist(), SIZE, PARAMS)
    assert (kind, panorama) == ("PANO", "FISHEYE_LENS_POLYNOMIAL")
    assert float(k1) == pytest.approx(f.polynomial[1], rel=1e-6)
    assert float(shift_x) == pytest.approx(f.shift_x, abs=1e-7)


#: the render lens with COLMAP's RAD_TAN_THIN_PRISM_FISHEYE terms
PARAMS_TP = PARAMS | {"k5": 2e-5, "k6": -1e-6, "p1": 4e-4, "p2": -3e-4, "s1": 5e-4, "s2": -1e-4, "s3": -4e-4, "s4": 1e-4}


def test_thin_prism_fisheye_radial_part_exact_and_the_rest_reported(addon, tmp_path):
    """kannala-brandt-thin-prism: Cycles gets the six-term radial part (fitted as for kannala-brandt), the
    tangential and thin-prism terms are left out and their size over the frame is what the mapping reports."""
    m = addon.fisheye
    radial = {k: PARAMS_TP[k] for k in ("k1", "k2", "k3", "k4", "k5", "k6")}
    radial |= dict.fromkeys(("p1", "p2", "s1", "s2", "s3", "s4"), 0.0)
    f = m.blender_fisheye(K.tolist(), SIZE, PARAMS_TP)
    u, v = np.meshgrid(np.arange(0.0, SIZE[0], 2.0), np.arange(0.0, SIZE[1], 2.0))
    pixels = np.column_stack([u.ravel(), v.ravel()])
    rays = np.array([m.fisheye_polynomial_ray(f, p) for p in pixels], dtype=float)
    radial_only = Distortion("kannala-brandt-thin-prism", radial).project_rays(rays, K)
    assert np.max(np.linalg.norm(radial_only - pixels, axis=1)) <= f.fit_max_px * 1.05 + 1e-9 < 0.01
    full = Distortion("kannala-brandt-thin-prism", PARAMS_TP).project_rays(rays, K)
    left_out = float(np.max(np.linalg.norm(full - radial_only, axis=1)))
    reported = m.thin_prism_offset_px(K.tolist(), SIZE, PARAMS_TP, step=2)
    print(f"thin prism left out: {left_out:.4f} px, reported {reported:.4f} px")
    assert reported == pytest.approx(left_out, rel=0.05)
    rig = addon.rigfile.load_rig(str(write_rig(tmp_path / "tp.rig.json", [camera_dict(
        "fish", SIZE, K, distortion={"model": "kannala-brandt-thin-prism", "params": PARAMS_TP})])))
    assert rig.cameras[0].distortion.model in addon.rigfile.FISHEYE_MODELS


def test_division_aspect_distorts_like_camcal(addon):
    m = addon.tracking
    lens = Distortion("division", {"lambda": -1.5e-7, "aspect": 2.0})
    Kd = np.array([[1400.0, 0.0, 641.3], [0.0, 700.0, 357.8], [0.0, 0.0, 1.0]])
    rng = np.random.default_rng(3)
    ideal = rng.uniform([0.0, 0.0], [1280.0, 720.0], (50, 2))
    ours = np.array([m.division_distort(p, (641.3, 357.8), -1.5e-7, 2.0) for p in ideal])
    assert np.abs(ours - lens.distort(ideal, Kd)).max() < 1e-9
    back = np.array([m.division_undistort(p, (641.3, 357.8), -1.5e-7, 2.0) for p in ours])
    assert np.abs(back - ideal).max() < 1e-9
    rig_lens = addon.rigfile.Distortion("division", {"lambda": -1.5e-7, "aspect": 2.0}, (641.3, 357.8))
    blender = m.blender_lens(rig_lens, Kd.tolist(), (1280, 720))
    assert not blender.exact and "aspect" in blender.note
