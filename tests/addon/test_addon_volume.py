"""A capture volume in Blender: every camera of an 8-camera rig placed, each projecting as camcal's camera does."""

import sys
from pathlib import Path

import numpy as np

from addon_helpers import blender_project, points_in_view
from addon_helpers import addon, bpy  # noqa: F401  (fixtures)
from camcal.model.rig import Rig

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "geometry"))
from capture_volume import make_volume  # noqa: E402


def test_every_camera_of_a_capture_volume_projects_as_camcal(bpy, addon, tmp_path):
    volume = make_volume(8, 1, image_size=(1280, 720), radius=2.5, seed=9)
    path = Rig(tuple(volume.cameras)).save(tmp_path / "volume.rig.json")
    scene = bpy.context.scene
    result = addon.import_rig(scene, str(path))
    assert sorted(result.cameras) == sorted(c.name for c in volume.cameras)
    assert len([o for o in scene.objects if o.type == "CAMERA"]) == 8
    assert {v.name for v in scene.render.views if v.use} == {c.name for c in volume.cameras}
    rng = np.random.default_rng(4)
    worst, centres = 0.0, []
    for camera in volume.cameras:
        obj = result.cameras[camera.name]
        X = points_in_view(camera.K, camera.R, camera.c, camera.image_size, 100, rng, depth=(1.0, 4.0))
        X = np.vstack([X, rng.uniform(-0.3, 0.3, (20, 3))])  # and the middle of the volume, seen by all
        worst = max(worst, float(np.abs(blender_project(bpy, obj, scene, X) - camera.project(X)).max()))
        centres.append(np.linalg.norm(np.array(obj.matrix_world.translation) - camera.c))
    print(f"\n8 cameras: worst projection difference Blender - camcal {worst:.2e} px, "
          f"worst centre {max(centres):.2e} m")
    assert worst < 1e-3 and max(centres) < 1e-6
