"""A zoom imported into Blender (bpy module): the camera's lens and shift keyed per frame, the tracking lens per frame.

At each frame the Blender camera's own projection (its matrices at that frame) is compared with camcal's
``camera_at_frame(...).project`` (pinhole part), and the lens clip's tracking camera, set at that frame, distorts like
camcal's lens of that frame (Blender's formulas, :func:`addon.tracking.blender_distort`).
"""

import importlib
import json

import numpy as np
import pytest

from addon_helpers import addon, blender_project, bpy, points_in_view  # noqa: F401  (fixtures)
from addon_helpers import compositor_tree
from camcal.model.camera import look_at
from camcal.model.distortion import Distortion
from camcal.model.rig import Camera, Frame, Lens, Rig

SIZE = (640, 360)
FRAME_START = 1
ZOOMS = (1.0, 1.2, 1.45, 1.7)


def zoom_rig() -> Rig:
    """A dolly of 4 frames zooming in; the barrel (OpenCV k1, k2 and tangential terms) easing with the zoom."""
    K = np.array([[520.0, 0.0, 322.4], [0.0, 520.0, 178.9], [0.0, 0.0, 1.0]])
    base = Distortion("opencv", {"k1": -0.18, "k2": 0.05, "p1": 4e-4, "p2": -3e-4, "k3": 0.0})
    camera = Camera("cam", SIZE, K, base, np.eye(3), np.zeros(3), sensor_width_mm=24.0)
    frames = []
    for i, zoom in enumerate(ZOOMS):
        K_frame = K.copy()
        K_frame[:2, :2] *= zoom
        K_frame[:2, 2] += (3.0 * i, -1.5 * i)
        lens = Distortion("opencv", {**base.params, "k1": -0.18 / zoom, "k2": 0.05 / zoom ** 2})
        centre = np.array([0.4 * i, -3.0 + 0.2 * i, 1.3])
        lenses = {} if i == 0 else {"cam": Lens(K_frame, lens, focal_mm=24.0 * zoom)}
        frames.append(Frame(10 + i, look_at(centre, [0.0, 3.0, 1.0]), centre, lenses=lenses))
    return Rig((camera,), frames=tuple(frames))


def tracking_lens_now(addon, clip, size):
    """The clip's tracking camera as it is now, as a :class:`addon.tracking.BlenderLens`."""
    camera = clip.tracking.camera
    names = json.loads(clip[addon.lens_animation.LENS_KEYS])
    params = {name: getattr(camera, name) for name in next(iter(names.values()))["params"]}
    return addon.tracking.BlenderLens(camera.distortion_model, params, camera.focal_length_pixels,
                                      tuple(camera.principal_point_pixels), size, True, "")


def test_each_frame_projects_like_camcal_at_that_frame(bpy, addon, tmp_path):
    rig = zoom_rig()
    path = rig.save(tmp_path / "zoom.rig.json")
    scene = bpy.context.scene
    result = addon.import_rig(scene, str(path), frame_start=FRAME_START, compositor=False)
    obj, clip = result.cameras["cam"], result.clips["cam"]
    assert obj.data.animation_data is not None and addon.lens_animation.LENS_KEYS in clip
    rng = np.random.default_rng(5)
    lenses_seen = set()
    for frame in reversed(rig.frames):  # out of order: each frame change sets the lens from its keys
        scene.frame_set(FRAME_START + frame.index)
        camera = rig.camera_at_frame("cam", frame.index)
        X = points_in_view(camera.K, camera.R, camera.c, SIZE, 200, rng)
        pinhole = Camera("p", SIZE, camera.K, Distortion.none(), camera.R, camera.c).project(X)
        projection_px = np.abs(blender_project(bpy, obj, scene, X) - pinhole).max()
        # the tracking camera at this frame distorts like camcal's lens at this frame
        lens = tracking_lens_now(addon, clip, SIZE)
        ideal = rng.uniform([0, 0], [SIZE[0] - 1, SIZE[1] - 1], (200, 2))
        blender = np.array([addon.tracking.blender_distort(lens, tuple(p)) for p in ideal])
        lens_px = np.abs(blender - camera.distortion.distort(ideal, camera.K)).max()
        print(f"frame {frame.index}: projection {projection_px:.1e} px, tracking lens {lens_px:.1e} px")
        assert projection_px < 1e-3 and lens_px < 1e-3
        lenses_seen.add(round(obj.data.lens, 9))
    assert len(lenses_seen) == len(ZOOMS)
    assert obj.data["camcal_lens_frames"] == len(ZOOMS) - 1


def test_the_handler_is_registered_once_and_holds_between_keys(bpy, addon, tmp_path):
    importlib.import_module(f"{addon.__name__}.lens_animation").ensure_handler()
    result = addon.import_rig(bpy.context.scene, str(zoom_rig().save(tmp_path / "zoom.rig.json")),
                              frame_start=FRAME_START, compositor=False)
    handlers = [h for h in bpy.app.handlers.frame_change_pre if h.__name__ == "apply_lens_keys"]
    assert len(handlers) == 1
    clip = result.clips["cam"]
    keys = json.loads(clip[addon.lens_animation.LENS_KEYS])
    assert sorted(int(k) for k in keys) == [FRAME_START + 10 + i for i in range(len(ZOOMS))]
    bpy.context.scene.frame_set(FRAME_START + 100)  # after the last key: the last lens holds
    last = keys[str(FRAME_START + 13)]
    assert clip.tracking.camera.focal_length_pixels == pytest.approx(last["focal_length_pixels"], rel=1e-6)
    assert clip.tracking.camera.brown_k1 == pytest.approx(last["params"]["brown_k1"], rel=1e-6)


def project_in_scene(obj, scene, X):
    """Blender's projection through ``obj`` as ``scene`` evaluates it (the overscan scene renders its own depsgraph)."""
    depsgraph = scene.view_layers[0].depsgraph
    evaluated = obj.evaluated_get(depsgraph)
    W, H = scene.render.resolution_x, scene.render.resolution_y
    P = np.array(evaluated.calc_matrix_camera(depsgraph, x=W, y=H, scale_x=scene.render.pixel_aspect_x,
                                              scale_y=scene.render.pixel_aspect_y))
    clip = np.c_[X, np.ones(len(X))] @ (P @ np.array(evaluated.matrix_world.inverted())).T
    ndc = clip[:, :2] / clip[:, 3:]
    return np.c_[(ndc[:, 0] + 1.0) / 2.0 * W - 0.5, (1.0 - ndc[:, 1]) / 2.0 * H - 0.5]


def test_the_overscan_render_camera_and_its_clip_follow_the_zoom(bpy, addon, tmp_path):
    """The compositor set-up: the overscan camera keyed like the camera, its Movie Distortion clip per frame."""
    rig = zoom_rig()
    scene = bpy.context.scene
    result = addon.import_rig(scene, str(rig.save(tmp_path / "zoom.rig.json")), frame_start=FRAME_START, overscan=1.2)
    dist_scene = result.distorted_scenes["cam"]
    os_obj = dist_scene.camera
    os_scene = bpy.data.scenes[f"{result.cameras['cam'].name} overscan"]
    mx, my = os_scene["camcal_overscan_margins"]
    size_os = (SIZE[0] + 2 * mx, SIZE[1] + 2 * my)
    tree = compositor_tree(addon, dist_scene)
    os_clip = [n.clip for n in tree.nodes if n.bl_idname == "CompositorNodeMovieDistortion"][0]
    rng = np.random.default_rng(8)
    for frame in rig.frames:
        scene.frame_set(FRAME_START + frame.index)  # the handler sets the clips' lenses
        os_scene.frame_set(FRAME_START + frame.index)
        camera = rig.camera_at_frame("cam", frame.index)
        K_os = camera.K + [[0, 0, mx], [0, 0, my], [0, 0, 0]]
        X = points_in_view(K_os, camera.R, camera.c, size_os, 100, rng)
        pinhole = Camera("p", size_os, K_os, Distortion.none(), camera.R, camera.c).project(X)
        assert np.abs(project_in_scene(os_obj, os_scene, X) - pinhole).max() < 1e-3
        lens = tracking_lens_now(addon, os_clip, size_os)
        ideal = rng.uniform([0, 0], [size_os[0] - 1, size_os[1] - 1], (100, 2))
        blender = np.array([addon.tracking.blender_distort(lens, tuple(p)) for p in ideal])
        assert np.abs(blender - camera.distortion.distort(ideal - [mx, my], camera.K) - [mx, my]).max() < 1e-3
    assert any("Movie Distortion offset" in w for w in result.warnings)


def test_a_zoom_blender_cannot_hold_is_refitted_frame_by_frame(addon):
    """camcal's side of ``camcal blender import``: each frame's 3DE lens becomes its nearest BROWN lens."""
    from camcal.blender_bridge import blender_tracking_rig
    from camcal.io.conversion import max_pixel_residual

    size = (160, 120)
    K = np.array([[150.0, 0.0, 80.2], [0.0, 150.0, 59.7], [0.0, 0.0, 1.0]])
    filmback = {"filmback_width_px": 160.0, "filmback_height_px": 120.0}
    camera = Camera("cam", size, K, Distortion("3de4-radial-deg4", {"c2": -0.04, "c4": 0.006, **filmback}),
                    np.eye(3), np.zeros(3))
    frames = [Frame(index, np.eye(3), np.zeros(3), lenses={} if index == 0 else {"cam": Lens(
        K * [[1 + 0.2 * index], [1 + 0.2 * index], [1]],
        Distortion("3de4-radial-deg4", {"c2": -0.04 / (1 + index), "c4": 0.006, **filmback}), focal_mm=20.0 + index)})
        for index in range(3)]
    rig = Rig((camera,), frames=tuple(frames))
    tracking, [conversion] = blender_tracking_rig(rig)
    residuals = []
    for frame in rig.frames:
        fitted = tracking.camera_at_frame("cam", frame.index)
        assert fitted.distortion.model == "opencv"
        residuals.append(max_pixel_residual(rig.camera_at_frame("cam", frame.index), fitted))
        lens = addon.rigfile.Distortion("opencv", dict(fitted.distortion.params), (fitted.K[0, 2], fitted.K[1, 2]))
        assert addon.tracking.blender_lens(lens, fitted.K.tolist(), size).exact
    assert tracking.frames[2].lenses["cam"].focal_mm == 22.0
    assert conversion.max_px == max(residuals) and 1e-5 < conversion.max_px < 1.0
