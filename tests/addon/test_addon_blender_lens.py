"""Blender's tracking-camera lens models against camcal's lenses.

The fast tests check :func:`tracking.blender_distort` (Blender's formulas,
libmv's ``distortion_models.h``) with the settings :func:`tracking.blender_lens`
chooses against camcal's own ``Distortion.distort``. The bpy ones (a few
seconds each) make Blender itself evaluate the lens: the add-on's distortion compositor (Movie
Distortion on the overscan frame, then the Translate that cancels its offset)
takes a coordinate ramp instead of the overscan render, so each output pixel
holds the position of the undistorted pixel Blender sampled for it; camcal's
lens applied to that position must give the output pixel back.
"""

import subprocess
import sys

import numpy as np
import pytest

from addon_helpers import camera_dict, compositor_tree, write_rig
from addon_helpers import addon, bpy  # noqa: F401  (fixtures)
from camcal.model.distortion import Distortion

POLYNOMIAL = {"model": "polynomial", "params": {"k1": -0.08, "k2": 0.012, "k3": -0.002}}
OPENCV = {"model": "opencv", "params": {"k1": -0.06, "k2": 0.01, "p1": 0.002, "p2": -0.003, "k3": 0.001}}
DIVISION = {"model": "division", "params": {"lambda": -4e-6}}

# (camcal lens, Blender model, frame size); NUKE in portrait: its radius is normalised by max(W, H) / 2.
CASES = {
    "POLYNOMIAL": (POLYNOMIAL, "POLYNOMIAL", (240, 180)),
    "DIVISION": (POLYNOMIAL, "DIVISION", (240, 180)),
    "NUKE": (DIVISION, "NUKE", (180, 240)),
    "BROWN": (OPENCV, "BROWN", (240, 180)),
}


def _K(size):
    return np.array([[260.0, 0.0, size[0] / 2 + 6.3], [0.0, 260.0, size[1] / 2 - 5.4], [0.0, 0.0, 1.0]])


def _lenses(addon, lens, model, size, margins=(0, 0)):
    """camcal's lens (model.distortion) and the add-on's tracking lens for it (rigfile -> mapping)."""
    K = _K(size)
    centre = [K[0, 2] - 3.1, K[1, 2] + 2.2] if lens["model"] == "division" else None
    data = dict(lens, center=centre) if centre else lens
    camcal_lens = Distortion.from_dict(data)
    rig_lens = addon.rigfile.Distortion(lens["model"], dict(lens["params"]),
                                        tuple(centre) if centre else (K[0, 2], K[1, 2]))
    return K, camcal_lens, data, addon.tracking.blender_lens(rig_lens, K.tolist(), size, margins, model)


@pytest.mark.parametrize("name", list(CASES))
@pytest.mark.parametrize("margins", [(0, 0), (12, 9)])
def test_blender_formulas_reproduce_camcal_lenses(addon, name, margins):
    lens, model, size = CASES[name]
    K, camcal_lens, _, blender = _lenses(addon, lens, model, size, margins)
    points = np.random.default_rng(4).uniform([-0.5, -0.5], [size[0] - 0.5, size[1] - 0.5], (400, 2))
    ours = camcal_lens.distort(points, K)
    theirs = np.array([addon.tracking.blender_distort(blender, p + margins) for p in points]) - margins
    error = np.abs(ours - theirs).max()
    print(f"{lens['model']} -> {model}: exact {blender.exact}, fit {blender.fit_max_px:.2e} px, "
          f"formula vs camcal {error:.2e} px")
    assert blender.distortion_model == model
    if blender.exact:
        assert blender.fit_max_px == 0.0 and error < 1e-9
    else:
        assert f"{model} model fitted" in blender.note
        assert 1e-6 < error <= blender.fit_max_px < 0.01


def test_brown_terms_and_refusals(addon):
    """libmv's BROWN: OpenCV's p1 / p2 exchanged (and y up), k4 an r^8 term camcal's lenses leave at 0."""
    _, _, _, blender = _lenses(addon, OPENCV, "BROWN", (240, 180))
    p = blender.params
    assert (p["brown_p1"], p["brown_p2"], p["brown_k4"]) == (-0.003, -0.002, 0.0)
    # an r^8 term moves a point at normalised radius r by k4 r^9 focal lengths along the radius
    bumped = addon.tracking.BlenderLens(**{**blender.__dict__, "params": dict(p, brown_k1=0.0, brown_k2=0.0,
                                                                             brown_k3=0.0, brown_p1=0.0,
                                                                             brown_p2=0.0, brown_k4=0.01)})
    cx, cy = blender.principal_point_pixels
    x0, y0 = addon.tracking.from_blender_pixel((cx + 130.0, cy), 180)
    moved = addon.tracking.blender_distort(bumped, (x0, y0))[0] - x0
    assert moved == pytest.approx(0.01 * (130.0 / 260.0) ** 9 * 260.0, rel=1e-12)
    rig = addon.rigfile.Distortion
    with pytest.raises(ValueError, match="no tangential terms"):
        addon.tracking.blender_lens(rig("opencv", dict(OPENCV["params"]), (126.3, 84.6)), _K((240, 180)).tolist(),
                                   (240, 180), model="NUKE")
    with pytest.raises(ValueError, match="unknown Blender distortion model"):
        addon.tracking.blender_lens(rig("polynomial", {"k1": 0.1, "k2": 0.0}, (126.3, 84.6)), _K((240, 180)).tolist(),
                                   (240, 180), model="FISHEYE")


def _ramp(bpy, size):
    """A float image whose pixel (i, j) (Blender's rows, bottom-up) holds ((i + 0.5) / W, (j + 0.5) / H)."""
    W, H = size
    image = bpy.data.images.new("camcal test ramp", W, H, alpha=True, float_buffer=True)
    pixels = np.ones((H, W, 4), dtype=np.float32)
    pixels[:, :, 0] = ((np.arange(W) + 0.5) / W)[None, :]
    pixels[:, :, 1] = ((np.arange(H) + 0.5) / H)[:, None]
    pixels[:, :, 2] = 0.0
    image.pixels.foreach_set(pixels.ravel())
    image.update()
    return image


def _sampled_positions(bpy, addon, dist_scene, node, size, margins, tmp_path):
    """Render ``dist_scene``'s compositor with a coordinate ramp of the overscan frame fed into ``node`` in place of
    the render: for each output pixel, where Blender sampled, as a camcal pixel of the camera's frame (H, W, 2)."""
    (W, H), (mx, my) = size, margins
    Wo, Ho = W + 2 * mx, H + 2 * my
    tree = compositor_tree(addon, dist_scene)
    for other in [n for n in tree.nodes if n.bl_idname in ("CompositorNodeRLayers", "CompositorNodeScale")]:
        tree.nodes.remove(other)
    ramp = tree.nodes.new("CompositorNodeImage")
    ramp.image = _ramp(bpy, (Wo, Ho))
    tree.links.new(ramp.outputs["Image"], node.inputs["Image"])
    dist_scene.render.image_settings.file_format = "OPEN_EXR"
    dist_scene.render.image_settings.color_depth = "32"
    dist_scene.render.filepath = str(tmp_path / "sampled.exr")
    bpy.ops.render.render(write_still=True, scene=dist_scene.name)
    image = bpy.data.images.load(dist_scene.render.filepath)
    assert tuple(image.size) == size
    pixels = np.empty(W * H * 4, dtype=np.float32)
    image.pixels.foreach_get(pixels)
    pixels = pixels.reshape(H, W, 4)[::-1].astype(np.float64)  # rows top-down: camcal's y
    # Blender's sampling position (overscan frame, edges, y up) -> camcal pixel of the camera's frame
    return np.stack([pixels[..., 0] * Wo - 0.5 - mx, Ho - pixels[..., 1] * Ho - 0.5 - my], axis=-1)


@pytest.mark.parametrize("name", list(CASES))
def test_movie_distortion_in_blender_equals_camcal_within_0_01_px(bpy, addon, tmp_path, name):
    lens, model, size = CASES[name]
    K, camcal_lens, data, blender = _lenses(addon, lens, model, size)
    W, H = size
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"  # the distortion scenes copy it; nothing is rendered but the compositor
    scene.cycles.samples = 1
    rig = write_rig(tmp_path / "lens.rig.json", [camera_dict("cam", size, K, distortion=data)])
    result = addon.import_rig(scene, str(rig), aux_directory=str(tmp_path / "lens"), lens_model=model)
    dist_scene = result.distorted_scenes["cam"]
    mx, my = bpy.data.scenes[f"{result.cameras['cam'].name} overscan"]["camcal_overscan_margins"]
    Wo, Ho = W + 2 * mx, H + 2 * my
    tree = compositor_tree(addon, dist_scene)
    md = next(node for node in tree.nodes if node.bl_idname == "CompositorNodeMovieDistortion")
    assert md.clip.tracking.camera.distortion_model == model
    sampled = _sampled_positions(bpy, addon, dist_scene, md, size, (mx, my), tmp_path)
    v, u = np.mgrid[0:H, 0:W]
    output = np.stack([u, v], axis=-1).astype(np.float64)
    # pixels whose sample lies in the ramp (bilinear reads of a ramp are exact there, clamped beyond)
    inside = ((sampled[..., 0] >= 0.5 - mx) & (sampled[..., 0] <= W + mx - 1.5)
              & (sampled[..., 1] >= 0.5 - my) & (sampled[..., 1] <= H + my - 1.5))
    inside[[0, -1], :] = inside[:, [0, -1]] = False
    ideal = sampled[inside]
    camcal_error = np.linalg.norm(camcal_lens.distort(ideal, K) - output[inside], axis=1)
    formula = np.array([addon.tracking.blender_distort(blender, p) for p in ideal[::7]])
    formula_error = np.linalg.norm(formula - output[inside][::7], axis=1)
    moved = np.linalg.norm(ideal - output[inside], axis=1).max()
    print(f"{lens['model']} lens as Blender's {model} ({W}x{H}, overscan {Wo}x{Ho}): Blender vs camcal "
          f"max {camcal_error.max():.4f} px, RMS {np.sqrt(np.mean(camcal_error ** 2)):.4f} px over {inside.sum()} "
          f"pixels; vs Blender's formula max {formula_error.max():.4f} px; fit {blender.fit_max_px:.4f} px; "
          f"the lens moves pixels up to {moved:.1f} px; offset {list(dist_scene['camcal_distortion_shift_px'])}")
    assert inside.mean() > 0.9 and moved > 3.0
    assert formula_error.max() < 0.01
    assert camcal_error.max() < 0.01


RATIONAL = {"model": "opencv", "params": {"k1": -0.21, "k2": 0.04, "p1": 8e-4, "p2": -1.2e-3, "k3": -0.004,
                                          "k4": 0.05, "k5": 0.012, "k6": 0.002, "s1": 1.1e-3, "s2": -4e-4}}


def test_camcal_side_refit_of_the_lenses_blender_cannot_hold(addon, tmp_path):
    """camcal replaces a lens no tracking model holds by its nearest opencv / division lens and reports the
    residual; the add-on then holds the fitted lens exactly."""
    from camcal.blender_bridge import blender_tracking_rig
    from camcal.io.conversion import max_pixel_residual
    from camcal.model.rig import Rig

    size = (320, 240)
    K = _K(size)
    aspect = {"model": "division", "params": {"lambda": -3e-6, "aspect": 1.02}}
    tde = {"model": "3de4-radial-deg4", "params": {"c2": -0.04, "u2": 0.004, "c4": 0.006,
                                                   "filmback_width_px": float(size[0]),
                                                   "filmback_height_px": float(size[1])}}
    rig = Rig.load(write_rig(tmp_path / "mixed.rig.json", [
        camera_dict("rational", size, K, distortion=RATIONAL), camera_dict("plain", size, K, distortion=OPENCV),
        camera_dict("oval", size, K, distortion=aspect), camera_dict("tde", size, K, distortion=tde)]))
    tracking, conversions = blender_tracking_rig(rig)
    assert tracking.camera("plain") == rig.camera("plain")
    assert [c.camera for c in conversions] == ["rational", "oval", "tde"]
    for conversion in conversions:
        source, fitted = rig.camera(conversion.camera), tracking.camera(conversion.camera)
        print(conversion.describe())
        assert not conversion.exact and conversion.max_px == max_pixel_residual(source, fitted)
        assert 1e-4 < conversion.max_px < 1.0 and "max residual" in conversion.describe()
        rig_lens = addon.rigfile.Distortion(fitted.distortion.model, dict(fitted.distortion.params),
                                            fitted.distortion.center or (K[0, 2], K[1, 2]))
        assert addon.tracking.blender_lens(rig_lens, fitted.K.tolist(), size).exact


def test_cli_blender_import_reports_the_refit(tmp_path, capsys):
    pytest.importorskip("bpy")
    from camcal.cli import main

    rig = write_rig(tmp_path / "r.rig.json", [camera_dict("cam", (320, 240), _K((320, 240)), distortion=RATIONAL)])
    assert main(["blender", "import", str(rig), "--blend", str(tmp_path / "r.blend")]) == 0
    captured = capsys.readouterr()
    assert "camera 'cam': opencv -> Blender BROWN: nearest fit, max residual" in captured.out + captured.err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["r.blend", "r.rig.json", "r_lens"]
    assert (tmp_path / "r_lens" / "cam_blender_uv.exr").is_file()
    script = ("import bpy, sys; bpy.ops.wm.open_mainfile(filepath=sys.argv[1]); "
              "s = [s for s in bpy.data.scenes if s.name.endswith(' distorted')][0]; "
              "t = s.compositor_effects.active.node_group if hasattr(s, 'compositor_effects') else s.compositing_node_group; "
              "print(sorted(n.bl_idname for n in t.nodes))")
    proc = subprocess.run([sys.executable, "-c", script, str(tmp_path / "r.blend")], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    assert "CompositorNodeMapUV" in proc.stdout and "CompositorNodeMovieDistortion" not in proc.stdout


def test_map_uv_path_in_blender_equals_camcal_within_0_01_px(bpy, addon, tmp_path):
    """A lens no tracking model holds (OpenCV's rational and thin-prism terms): the compositor re-distorts with
    camcal's own map through Map UV; a coordinate ramp in place of the overscan render comes out as camcal's lens."""
    from camcal.blender_bridge import write_blender_uv_maps
    from camcal.model.rig import Rig

    size = (240, 180)
    W, H = size
    K = _K(size)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.samples = 1
    rig_path = write_rig(tmp_path / "rational.rig.json", [camera_dict("cam", size, K, distortion=RATIONAL)])
    uv_maps = write_blender_uv_maps(Rig.load(rig_path), ["cam"], tmp_path / "uv", overscan=1.1)
    result = addon.import_rig(scene, str(rig_path), aux_directory=str(tmp_path / "lens"), uv_maps=uv_maps)
    dist_scene = result.distorted_scenes["cam"]
    mx, my = addon.tracking.overscan_margins(size, 1.1)
    tree = compositor_tree(addon, dist_scene)
    map_uv = next(node for node in tree.nodes if node.bl_idname == "CompositorNodeMapUV")
    assert not [n for n in tree.nodes if n.bl_idname == "CompositorNodeMovieDistortion"]
    sampled = _sampled_positions(bpy, addon, dist_scene, map_uv, size, (mx, my), tmp_path)
    v, u = np.mgrid[0:H, 0:W]
    output = np.stack([u, v], axis=-1).reshape(-1, 2).astype(np.float64)
    lens = Distortion.from_dict(RATIONAL)
    source = lens.undistort(output, K)  # where camcal's lens samples the render for each output pixel
    # output pixels whose source lies in the overscan render, a pixel from its edge (Map UV clips beyond)
    inside = ((source[:, 0] >= 0.5 - mx) & (source[:, 0] <= W + mx - 1.5)
              & (source[:, 1] >= 0.5 - my) & (source[:, 1] <= H + my - 1.5))
    sampled = sampled.reshape(-1, 2)[inside]
    error = np.linalg.norm(lens.distort(sampled, K) - output[inside], axis=1)
    moved = np.linalg.norm(source[inside] - output[inside], axis=1).max()
    print(f"opencv rational + thin prism lens through Map UV: Blender vs camcal max {error.max():.4f} px over "
          f"{inside.sum()} pixels; the lens moves pixels up to {moved:.1f} px")
    assert inside.mean() > 0.98 and moved > 3.0
    assert error.max() < 0.01
