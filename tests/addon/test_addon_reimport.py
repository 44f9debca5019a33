"""Re-importing a rig replaces its earlier import in place; ``camcal blender import --into`` adds to a .blend."""

import numpy as np
import pytest

from addon_helpers import camera_dict, frame, write_rig
from addon_helpers import addon, bpy  # noqa: F401  (fixtures)
from camcal.cli import main

K = [[700.0, 0, 320.0], [0, 700.0, 240.0], [0, 0, 1]]
DIVISION = {"model": "division", "params": {"lambda": -2e-7}}


def _rig(path, shift=0.0, distortion=None):
    """Two cameras (``b`` with ``distortion``) and two frames; ``shift`` moves the rig along x."""
    cams = [camera_dict("a", (640, 480), K), camera_dict("b", (640, 480), K, c=(0.3, 0, 0), distortion=distortion)]
    return write_rig(path, cams, [frame(0, c=(shift, 0, 0)), frame(1, c=(shift, 0.5, 0))])


def _counts(bpy):
    """Objects in scenes, scenes, clips, collections, cameras in scenes and actions in use."""
    objects = {o for s in bpy.data.scenes for o in s.objects}
    return (len(objects), len(bpy.data.scenes), len(bpy.data.movieclips), len(bpy.data.collections),
            len({o.data for o in objects if o.type == "CAMERA"}), len([a for a in bpy.data.actions if a.users]))


def test_reimport_replaces_the_rig_in_place(bpy, addon, tmp_path):
    import importlib

    reimport = importlib.import_module(f"{addon.__name__}.reimport")
    scene = bpy.context.scene
    path = _rig(tmp_path / "shot.rig.json", distortion=DIVISION)
    first, replaced = reimport.import_in_place(scene, str(path), compositor=False)
    assert not replaced and first.clips  # camera b's lens clip
    # the user files the rig under a collection of theirs and hangs a prop on camera a
    layout = bpy.data.collections.new("layout")
    scene.collection.children.link(layout)
    layout.children.link(first.collection)
    scene.collection.children.unlink(first.collection)
    prop = bpy.data.objects.new("prop", None)
    scene.collection.objects.link(prop)
    prop.parent = first.cameras["a"]
    counts = _counts(bpy)

    _rig(tmp_path / "shot.rig.json", shift=2.0, distortion=DIVISION)  # solved again: the rig moved
    second, replaced = reimport.import_in_place(scene, str(path), compositor=False)
    assert replaced and _counts(bpy) == counts
    assert second.collection.name == "shot" and [c.name for c in layout.children] == ["shot"]
    assert second.collection.name not in scene.collection.children
    assert prop.parent == second.cameras["a"] and second.cameras["a"].name == "shot_a"
    scene.frame_set(scene.frame_start + 1)
    np.testing.assert_allclose(second.cameras["a"].matrix_world.translation, (2.0, 0.5, 0.0), atol=1e-6)
    np.testing.assert_allclose(second.cameras["b"].matrix_world.translation, (2.3, 0.5, 0.0), atol=1e-6)

    third, replaced = reimport.import_in_place(scene, str(path), compositor=False, replace=False)
    assert not replaced and third.collection.name == "shot.001"
    assert _counts(bpy)[0] == 2 * counts[0] - 1  # a second rig beside the first (the prop once)


def test_reimport_removes_the_distortion_scenes_it_made(bpy, addon, tmp_path):
    """The compositor's scenes, overscan camera and lens clips of the earlier import go with it."""
    import importlib

    reimport = importlib.import_module(f"{addon.__name__}.reimport")
    scene = bpy.context.scene
    path = _rig(tmp_path / "lens.rig.json", distortion=DIVISION)
    reimport.import_in_place(scene, str(path))
    names = sorted(s.name for s in bpy.data.scenes), sorted(c.name for c in bpy.data.movieclips)
    assert names[0] == ["Scene", "lens_b distorted", "lens_b overscan"]
    counts = _counts(bpy)
    reimport.import_in_place(scene, str(path))
    assert (sorted(s.name for s in bpy.data.scenes), sorted(c.name for c in bpy.data.movieclips)) == names
    assert _counts(bpy) == counts


def test_blender_import_into_a_blend_that_holds_the_rig(bpy, addon, tmp_path, capsys):
    """The layout (a set piece and the rig's earlier import) gets the new solve in place of the old one."""
    import importlib

    scene_blend, rig = tmp_path / "layout.blend", _rig(tmp_path / "shot.rig.json")
    cube = bpy.data.objects.new("set piece", bpy.data.meshes.new("set piece"))
    bpy.context.scene.collection.objects.link(cube)
    importlib.import_module(f"{addon.__name__}.reimport").import_in_place(bpy.context.scene, str(rig))
    bpy.ops.wm.save_as_mainfile(filepath=str(scene_blend), copy=True)
    _rig(tmp_path / "shot.rig.json", shift=2.0)  # solved again: the rig moved

    out = tmp_path / "tracked.blend"
    assert main(["blender", "import", str(rig), "--into", str(scene_blend), "--blend", str(out)]) == 0
    assert f"re-imported rig 'shot' into {out} (scene 'Scene', collection 'shot')" in capsys.readouterr().out
    for path, x in ((scene_blend, 0.0), (out, 2.0)):  # the layout as it was; the new file with the new solve
        bpy.ops.wm.open_mainfile(filepath=str(path))
        assert sorted(o.name for o in bpy.data.objects) == ["set piece", "shot", "shot_a", "shot_b"]
        scene = bpy.context.scene
        scene.frame_set(scene.frame_start)
        np.testing.assert_allclose(bpy.data.objects["shot_a"].matrix_world.translation, (x, 0.0, 0.0), atol=1e-6)


def test_blender_import_needs_a_blend_and_names_a_bad_one(tmp_path, capsys):
    pytest.importorskip("bpy")
    rig = _rig(tmp_path / "shot.rig.json")
    assert main(["blender", "import", str(rig)]) == 2
    assert "give --blend OUT.blend (a new file) or --into SCENE.blend" in capsys.readouterr().err
    assert main(["blender", "import", str(rig), "--into", str(tmp_path / "none.blend")]) == 2
    assert ".blend file to import into not found" in capsys.readouterr().err
    (tmp_path / "text.blend").write_text("not a blend file")
    assert main(["blender", "import", str(rig), "--into", str(tmp_path / "text.blend")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("camcal: error: cannot open") and "text.blend" in err[0]
    assert (tmp_path / "text.blend").read_text() == "not a blend file"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["shot.rig.json", "text.blend"]


def test_the_import_operator_replaces_in_place(bpy, addon, tmp_path):
    addon.register()
    try:
        path = str(_rig(tmp_path / "op.rig.json"))
        assert bpy.ops.import_scene.camcal_rig(filepath=path) == {"FINISHED"}
        counts = _counts(bpy)
        _rig(tmp_path / "op.rig.json", shift=1.0)
        assert bpy.ops.import_scene.camcal_rig(filepath=path) == {"FINISHED"}
        assert _counts(bpy) == counts and bpy.data.objects["op"]["camcal_rig_path"] == path
        assert bpy.ops.import_scene.camcal_rig(filepath=path, replace_previous=False) == {"FINISHED"}
        assert _counts(bpy)[0] == 2 * counts[0] and sorted(c.name for c in bpy.data.collections) == ["op", "op.001"]
    finally:
        addon.unregister()
