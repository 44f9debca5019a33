"""``camcal blender import``: the headless path (a subprocess with bpy)."""

import subprocess
import sys

import pytest

from addon_helpers import camera_dict, write_rig
from camcal.cli import main

K = [[700.0, 0, 320.0], [0, 700.0, 240.0], [0, 0, 1]]


def test_help(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["blender", "import", "--help"])
    assert exit_info.value.code == 0
    assert "--blend" in capsys.readouterr().out


def test_bad_rig_is_one_line_exit_2(tmp_path, capsys):
    pytest.importorskip("bpy")
    bad = tmp_path / "bad.rig.json"
    bad.write_text('{"format": "camcal.rig", "version": 1, "cameras": [{"name": "a"}]}')
    out = tmp_path / "out.blend"
    assert main(["blender", "import", str(bad), "--blend", str(out)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    # camcal reads the rig before Blender starts: one line naming the file and the field
    assert len(err) == 1 and err[0].startswith(f"camcal: error: {bad}: ") and "missing key 'image_size'" in err[0]
    assert not out.exists()
    assert main(["blender", "import", str(tmp_path / "none.rig.json"), "--blend", str(out)]) == 2


def test_import_writes_a_blend_that_loads(tmp_path, capsys):
    pytest.importorskip("bpy")
    cams = [camera_dict("left", (640, 480), K), camera_dict("right", (640, 480), K, c=(0.1, 0, 0))]
    rig = write_rig(tmp_path / "pair.rig.json", cams)
    out = tmp_path / "pair.blend"
    assert main(["blender", "import", str(rig), "--blend", str(out)]) == 0
    assert "2 camera(s) (left, right), stereo: stereo_3d" in capsys.readouterr().out
    script = (
        "import bpy, sys; bpy.ops.wm.open_mainfile(filepath=sys.argv[1]); s = bpy.context.scene; "
        "print(s.camera.name, s.render.views_format, s.render.resolution_x, "
        "sorted(o.name for o in bpy.data.objects))"
    )
    proc = subprocess.run([sys.executable, "-c", script, str(out)], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    assert "pair_left STEREO_3D 640 ['pair', 'pair_left', 'pair_right']" in proc.stdout
