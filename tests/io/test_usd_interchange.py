"""USD export / import, checked with pxr's Gf.Camera and with Blender's own USD importer."""

import json
import subprocess
import sys

import numpy as np
import pytest
from pxr import Sdf, Usd, UsdGeom
from scipy.spatial.transform import Rotation

from camcal.base.errors import CamcalError
from camcal.model.distortion import Distortion
from camcal.io.interchange import export_rig, import_rig
from camcal.io.ply import read_points_ply
from camcal.model.rig import Camera, Rig

from interchange_rigs import K, SIZE, division_rig, fisheye_rig, moving_rig, stereo_rig, world_points

D = np.diag([1.0, -1.0, -1.0])


def ideal_pixels(camera, X):
    """camcal's pinhole projection (USD cameras have no lens)."""
    x = (X - camera.c) @ camera.R.T @ camera.K.T
    return x[:, :2] / x[:, 2:]


def gf_pixels(stage, camera_name, time, X_camcal, size, prim_path=None):
    """pxr's own projection: Gf.Camera's frustum, view then projection matrix, NDC to pixels."""
    gf_camera = UsdGeom.Camera(stage.GetPrimAtPath(prim_path or f"/rig/{camera_name}")).GetCamera(time)
    frustum = gf_camera.frustum
    M = np.array(frustum.ComputeViewMatrix()) @ np.array(frustum.ComputeProjectionMatrix())
    clip = np.column_stack([X_camcal @ D, np.ones(len(X_camcal))]) @ M
    ndc = clip[:, :2] / clip[:, 3:]
    width, height = size
    return np.column_stack([(ndc[:, 0] + 1) / 2 * width - 0.5, (1 - ndc[:, 1]) / 2 * height - 0.5])


@pytest.mark.parametrize("suffix", [".usda", ".usdc", ".usd"])
def test_static_rig_projects_like_camcal_in_pxr_and_round_trips(tmp_path, suffix):
    rig = stereo_rig(rectified=False)
    out = tmp_path / f"rig{suffix}"
    result = export_rig(rig, "usd", out)
    assert all(0 <= c.max_px < 1e-3 for c in result.conversions)  # 32-bit float attributes
    stage = Usd.Stage.Open(str(out))
    assert UsdGeom.GetStageUpAxis(stage) == UsdGeom.Tokens.y and UsdGeom.GetStageMetersPerUnit(stage) == 1.0
    worst = 0.0
    for camera in rig.cameras:
        X, _ = world_points(rig, camera)
        worst = max(worst, np.abs(gf_pixels(stage, camera.name, Usd.TimeCode.Default(), X, camera.image_size)
                                  - ideal_pixels(camera, X)).max())
    print(f"Gf.Camera vs camcal: {worst:.2e} px (printed: {max(c.max_px for c in result.conversions):.2e} px)")
    assert worst < 1e-3
    back = import_rig(out, "usd").rig
    for a, b in zip(rig.cameras, back.cameras):
        X, _ = world_points(rig, a)
        assert np.abs(a.project(X) - b.project(X)).max() < 1e-9
        assert a.distortion == b.distortion and a.name == b.name


def test_moving_rig_time_samples_points_and_frames(tmp_path):
    rig, rig_path = moving_rig(tmp_path)
    out = tmp_path / "moving.usda"
    export_rig(rig, "usd", out, rig_path=rig_path)
    stage = Usd.Stage.Open(str(out))
    assert (stage.GetStartTimeCode(), stage.GetEndTimeCode()) == (1001, 1005)
    worst = 0.0
    for frame in rig.frames:
        for camera in rig.cameras:
            posed = rig.camera_at_frame(camera.name, frame.index)
            X, _ = world_points(rig, posed)
            worst = max(worst, np.abs(gf_pixels(stage, camera.name, Usd.TimeCode(frame.index), X, camera.image_size)
                                      - ideal_pixels(posed, X)).max())
    assert worst < 1e-3
    points = UsdGeom.Points(stage.GetPrimAtPath("/rig/points"))
    stored = np.array(points.GetPointsAttr().Get())
    ply = read_points_ply(rig_path.parent / rig.points)
    assert np.abs(stored @ D - np.column_stack([ply["x"], ply["y"], ply["z"]])).max() < 1e-6  # float32
    back = import_rig(out, "usd").rig
    assert [f.index for f in back.frames] == [f.index for f in rig.frames]
    for frame in rig.frames:
        for camera in rig.cameras:
            a, b = rig.camera_at_frame(camera.name, frame.index), back.camera_at_frame(camera.name, frame.index)
            X, _ = world_points(rig, a)
            assert np.abs(a.project(X) - b.project(X)).max() < 1e-9


def test_fisheye_lens_rides_in_custom_data_exactly(tmp_path):
    rig = fisheye_rig(rectified=False)
    out = tmp_path / "fisheye.usda"
    result = export_rig(rig, "usd", out)
    assert all(0 <= c.max_px < 1e-3 for c in result.conversions)  # 32-bit float attributes, the lens exact
    stage = Usd.Stage.Open(str(out))
    worst = 0.0
    for camera in rig.cameras:
        custom = stage.GetPrimAtPath(f"/rig/{camera.name}").GetCustomData()["camcal"]
        lens = Distortion.from_dict(json.loads(custom["distortion"]))
        assert lens == camera.distortion and lens.model == "kannala-brandt"
        # pxr's pinhole projection with the lens from customData applied gives camcal's fisheye pixels
        X, pixels = world_points(rig, camera, n=500)
        ideal = gf_pixels(stage, camera.name, Usd.TimeCode.Default(), X, camera.image_size)
        K_custom = np.array(json.loads(custom["K"]))
        worst = max(worst, np.abs(lens.distort(ideal, K_custom) - pixels).max())
    print(f"Gf.Camera + customData kannala-brandt vs camcal: {worst:.2e} px")
    assert worst < 1e-3
    back = import_rig(out, "usd").rig
    for a, b in zip(rig.cameras, back.cameras):
        X, _ = world_points(rig, a)
        assert a.distortion == b.distortion and np.abs(a.project(X) - b.project(X)).max() < 1e-9


def test_skew_is_dropped_with_its_residual_and_an_edited_camera_is_read_from_its_attributes(tmp_path):
    rig = division_rig()
    out = tmp_path / "wide.usda"
    (conversion,) = export_rig(rig, "usd", out).conversions
    assert not conversion.exact and 0.1 < conversion.max_px < 1.0  # skew 0.8 px at most 0.45 of fy away
    stage = Usd.Stage.Open(str(out))
    camera = rig.cameras[0]
    X, _ = world_points(rig, camera, n=2000)
    observed = np.abs(gf_pixels(stage, "wide", Usd.TimeCode.Default(), X, SIZE) - ideal_pixels(camera, X)).max()
    assert observed <= conversion.max_px * 1.01
    # an artist changes the focal length in a DCC: the import follows the USD attribute
    layer = Sdf.Layer.FindOrOpen(str(out))
    stage = Usd.Stage.Open(layer)
    stage.GetPrimAtPath("/rig/wide").GetAttribute("focalLength").Set(50.0)
    layer.Save()
    back = import_rig(out, "usd").rig.cameras[0]
    assert back.K[0, 0] == pytest.approx(50.0 * SIZE[0] / 36.0, rel=1e-6)


BLENDER_SCRIPT = r"""
import json, sys
import bpy, numpy as np
path, frames = sys.argv[1], json.loads(sys.argv[2])
bpy.ops.wm.read_factory_settings(use_empty=True)
assert bpy.ops.wm.usd_import(filepath=path) == {'FINISHED'}
scene = bpy.context.scene
cloud = next(o for o in bpy.data.objects if o.type == 'POINTCLOUD')
out = {}
for frame in frames:
    scene.frame_set(frame)
    depsgraph = bpy.context.evaluated_depsgraph_get()
    X = np.array([list(cloud.matrix_world @ p.co) for p in cloud.data.points])
    for cam in (o for o in bpy.data.objects if o.type == 'CAMERA'):
        W, H = json.loads(sys.argv[3])[cam.name]
        scene.render.resolution_x, scene.render.resolution_y = W, H
        scene.render.pixel_aspect_x = scene.render.pixel_aspect_y = 1.0
        P = np.array(cam.calc_matrix_camera(depsgraph, x=W, y=H, scale_x=1.0, scale_y=1.0))
        V = np.array(cam.matrix_world.inverted())
        clip = (P @ V @ np.c_[X, np.ones(len(X))].T).T
        ndc = clip[:, :3] / clip[:, 3:]
        out[f"{cam.name}@{frame}"] = np.c_[(ndc[:, 0] + 1) / 2 * W - 0.5, (1 - ndc[:, 1]) / 2 * H - 0.5].tolist()
print("RESULT" + json.dumps(out))
"""


def test_blender_usd_importer_projects_like_camcal(tmp_path):
    pytest.importorskip("bpy")
    rig, rig_path = moving_rig(tmp_path)
    # square pixels (Blender's importer sets no pixel aspect) and principal points off centre
    cameras = (Camera("left", SIZE, K(1100.0, 1100.0, 655.25, 340.5), Distortion.none(), np.eye(3), np.zeros(3),
                      sensor_width_mm=36.0),
               Camera("right", (960, 720), K(900.0, 900.0, 470.0, 371.0), Distortion.none(),
                      Rotation.from_euler("y", -2.0, degrees=True).as_matrix(), [0.3, 0.0, 0.0]))
    rig = Rig(cameras, units="m", frames=rig.frames, points=rig.points)
    out = tmp_path / "moving.usdc"
    export_rig(rig, "usd", out, rig_path=rig_path)
    frames = [f.index for f in rig.frames]
    sizes = {c.name: list(c.image_size) for c in rig.cameras}
    proc = subprocess.run([sys.executable, "-c", BLENDER_SCRIPT, str(out), json.dumps(frames), json.dumps(sizes)],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    blender = json.loads(proc.stdout.split("RESULT", 1)[1])
    ply = read_points_ply(rig_path.parent / rig.points)
    X = np.column_stack([ply["x"], ply["y"], ply["z"]])
    worst = 0.0
    for frame in frames:
        for camera in rig.cameras:
            posed = rig.camera_at_frame(camera.name, frame)
            ours = ideal_pixels(posed, X)
            depth = ((X - posed.c) @ posed.R.T)[:, 2]
            keep = (depth > 0.1) & np.all((ours > -0.5) & (ours < np.array(camera.image_size) - 0.5), axis=1)
            assert keep.sum() > 20
            worst = max(worst, np.abs(np.array(blender[f"{camera.name}@{frame}"])[keep] - ours[keep]).max())
    print(f"Blender's USD importer + calc_matrix_camera vs camcal: {worst:.2e} px")
    assert worst < 1e-3


@pytest.mark.parametrize("text, message", [
    ("#usda 1.0\ndef Xform \"rig\" {}\n", "no UsdGeom.Camera"),
    ("#usda 1.0\ndef Camera \"cam\" {}\n", "has no image size"),
    ("not usd at all", "not a USD file"),
    ("#usda 1.0\ndef Camera \"cam\" (\n    customData = {\n        dictionary camcal = {\n"
     "            int[] image_size = [640, 480]\n        }\n    }\n)\n{\n    float focalLength = -5\n}\n",
     "must be positive"),
    ("#usda 1.0\ndef Camera \"cam\" (customData = {dictionary camcal = {int[] image_size = [640, 480]}})\n"
     "{ float focalLength = -5 }\n", r"not a USD file \(.*Expected \}"),
])
def test_bad_input_is_one_line(tmp_path, text, message):
    path = tmp_path / "bad.usda"
    path.write_text(text)
    with pytest.raises(CamcalError, match=message) as info:
        import_rig(path, "usd")
    assert "\n" not in str(info.value)


def test_stmaps_are_written_and_referenced(tmp_path):
    rig = stereo_rig(rectified=False)
    result = export_rig(rig, "usd", tmp_path / "rig.usda", stmaps=True)
    assert [p.name for p in result.paths[1:]] == ["left_undistort.exr", "left_redistort.exr",
                                                  "right_undistort.exr", "right_redistort.exr"]
    stage = Usd.Stage.Open(str(tmp_path / "rig.usda"))
    reference = stage.GetPrimAtPath("/rig/left").GetCustomDataByKey("camcal:stmap_undistort")
    assert reference.path == "rig_stmaps/left_undistort.exr" and (tmp_path / reference.path).is_file()
    with pytest.raises(CamcalError, match="stmaps applies to usd only"):
        export_rig(rig, "opencv", tmp_path / "rig.yaml", stmaps=True)


def test_nan_attribute_is_named(tmp_path):
    stage = Usd.Stage.CreateNew(str(tmp_path / "nan.usda"))
    camera = UsdGeom.Camera.Define(stage, "/rig/cam")
    camera.GetPrim().SetCustomData({"camcal": {"image_size": [640, 480]}})
    camera.CreateFocalLengthAttr(float("nan"))
    stage.Save()
    with pytest.raises(CamcalError, match="not finite"):
        import_rig(tmp_path / "nan.usda", "usd")


def test_units_and_bad_suffix(tmp_path):
    rig = stereo_rig(rectified=False)
    centimetres = Rig(rig.cameras, units="cm")
    export_rig(centimetres, "usd", tmp_path / "cm.usda")
    assert UsdGeom.GetStageMetersPerUnit(Usd.Stage.Open(str(tmp_path / "cm.usda"))) == 0.01
    assert import_rig(tmp_path / "cm.usda", "usd").rig.units == "cm"
    squares = export_rig(Rig(rig.cameras, units="squares"), "usd", tmp_path / "sq.usda")
    assert any("metersPerUnit written as 1" in note for note in squares.notes)
    with pytest.raises(CamcalError, match="must end in"):
        export_rig(rig, "usd", tmp_path / "rig.abc")
    assert not (tmp_path / "rig.abc").exists()


def plain_usd_camera(path, vertical_aperture):
    """A camera as another tool writes it with pxr: no camcal customData, xform ops, centimetres, Y up."""
    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.y)
    UsdGeom.SetStageMetersPerUnit(stage, 0.01)
    camera = UsdGeom.Camera.Define(stage, "/World/shotcam")
    camera.CreateFocalLengthAttr(35.0)
    camera.CreateHorizontalApertureAttr(36.0)
    camera.CreateVerticalApertureAttr(vertical_aperture)
    camera.CreateHorizontalApertureOffsetAttr(1.2)
    camera.CreateVerticalApertureOffsetAttr(-0.6)
    camera.AddTranslateOp().Set((120.0, 160.0, 450.0))
    camera.AddRotateXYZOp().Set((-12.0, 15.0, 2.0))
    stage.GetRootLayer().Save()


@pytest.mark.parametrize("vertical_aperture", [20.25, 24.0])  # 16:9 like the image, then a 3:2 back
def test_plain_usd_camera_needs_and_takes_an_image_size(tmp_path, vertical_aperture):
    path = tmp_path / "shotcam.usda"
    plain_usd_camera(path, vertical_aperture)
    with pytest.raises(CamcalError, match=r"no image size .*give it with --image-size W H") as info:
        import_rig(path, "usd")
    assert "\n" not in str(info.value)
    result = import_rig(path, "usd", image_size=(1920, 1080))
    (camera,) = result.rig.cameras
    assert camera.name == "shotcam" and camera.image_size == (1920, 1080) and result.rig.units == "cm"
    assert camera.distortion.model == "none"
    square = vertical_aperture == 20.25
    assert (camera.K[0, 0] == pytest.approx(camera.K[1, 1], rel=1e-6)) == square
    assert any("aperture aspect" in note for note in result.notes) != square
    # pxr's own Gf.Camera frustum of the same prim projects like the imported camera
    X, pixels = world_points(result.rig, camera, n=500)
    stage = Usd.Stage.Open(str(path))
    observed = np.abs(gf_pixels(stage, None, Usd.TimeCode.Default(), X, (1920, 1080), "/World/shotcam") - pixels).max()
    print(f"plain USD camera (aperture 36 x {vertical_aperture}): Gf.Camera vs imported camcal camera {observed:.1e} px")
    assert observed < 1e-6
    with pytest.raises(CamcalError, match="applies to usd, 3de and nuke only"):
        import_rig(path, "opencv", image_size=(1920, 1080))


def test_plain_usd_camera_through_the_cli(tmp_path, capsys):
    from camcal.cli import main

    path = tmp_path / "shotcam.usda"
    plain_usd_camera(path, 20.25)
    out = tmp_path / "shot.rig.json"
    assert main(["rig", "import", str(path), "--from", "usd", "--out", str(out)]) == 2
    error = capsys.readouterr().err.strip()
    assert "--image-size W H" in error and "\n" not in error and not out.exists()
    assert main(["rig", "import", str(path), "--from", "usd", "--image-size", "1920", "0", "--out", str(out)]) == 2
    assert "--image-size must be two positive integers" in capsys.readouterr().err and not out.exists()
    assert main(["rig", "import", str(path), "--from", "usd", "--image-size", "1920", "1080", "--out", str(out)]) == 0
    assert Rig.load(out).cameras[0].image_size == (1920, 1080)
