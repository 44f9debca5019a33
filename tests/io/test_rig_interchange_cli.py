"""`camcal rig export` / `camcal rig import`: help, summaries, bad input (one line, exit 2, nothing written)."""

import json

import numpy as np
import pytest

from camcal.cli import main
from camcal.model.rig import Rig

from interchange_rigs import division_rig, moving_rig, stereo_rig


@pytest.mark.parametrize("verb", ["export", "import"])
def test_help(verb, capsys):
    with pytest.raises(SystemExit) as info:
        main(["rig", verb, "--help"])
    assert info.value.code == 0
    assert "opencv, kalibr, colmap, usd, nuke" in capsys.readouterr().out


@pytest.mark.parametrize("fmt, name", [("opencv", "out.yaml"), ("kalibr", "camchain.yaml"), ("colmap", "model"),
                                       ("usd", "rig.usda"), ("nuke", "rig.nk")])
def test_every_format_exports_and_imports_through_the_cli(tmp_path, capsys, fmt, name):
    rig = stereo_rig(rectified=False)
    rig_path = rig.save(tmp_path / "in.rig.json")
    assert main(["rig", "export", str(rig_path), "--to", fmt, str(tmp_path / name)]) == 0
    printed = capsys.readouterr().out
    assert "camera 'left':" in printed and f"wrote {tmp_path / name}" in printed
    assert main(["rig", "import", str(tmp_path / name), "--from", fmt, "--out", str(tmp_path / "back.rig.json")]) == 0
    back = Rig.load(tmp_path / "back.rig.json")
    assert len(back.cameras) == 2
    assert back.provenance["method"] == "import" and back.provenance["format"] == fmt


def test_lossy_export_prints_the_residual(tmp_path, capsys):
    rig_path = division_rig().save(tmp_path / "wide.rig.json")
    assert main(["rig", "export", str(rig_path), "--to", "opencv", str(tmp_path / "wide.yaml")]) == 0
    assert "division with skew -> opencv (k1 k2 p1 p2 k3): nearest fit, max residual" in capsys.readouterr().out


def test_colmap_points_are_written_beside_the_imported_rig(tmp_path, capsys):
    rig, rig_path = moving_rig(tmp_path)
    assert main(["rig", "export", str(rig_path), "--to", "colmap", str(tmp_path / "model")]) == 0
    assert main(["rig", "import", str(tmp_path / "model"), "--from", "colmap", "--out", str(tmp_path / "sfm.rig.json")]) == 0
    back = json.loads((tmp_path / "sfm.rig.json").read_text())
    assert back["points"] == "sfm.points.ply" and (tmp_path / "sfm.points.ply").is_file()
    assert len(back["cameras"]) == 2 * len(rig.frames)


@pytest.mark.parametrize("args, message", [
    (["import", "{missing}", "--from", "opencv"], "opencv input not found"),
    (["import", "{bad_yaml}", "--from", "opencv"], "no camera_matrix"),
    (["import", "{bad_yaml}", "--from", "kalibr"], "not a Kalibr camchain|not a YAML file"),
    (["import", "{bad_yaml}", "--from", "usd"], "must end in|not a USD file"),
    (["export", "{rig}", "--to", "opencv", "{out_json}"], "must end in"),
    (["export", "{rig}", "--to", "usd", "{out_json}"], "must end in"),
    (["export", "{rig}", "--to", "opencv", "{out_yaml}", "--camera", "nobody"], "no camera 'nobody'"),
])
def test_bad_input_one_line_exit_2_nothing_written(tmp_path, capsys, args, message):
    rig_path = stereo_rig(rectified=False).save(tmp_path / "in.rig.json")
    (tmp_path / "bad.yaml").write_text("%YAML:1.0\n---\nimage_width: 640\n")
    paths = {"missing": tmp_path / "missing.yaml", "bad_yaml": tmp_path / "bad.yaml", "rig": rig_path,
             "out_json": tmp_path / "out.json", "out_yaml": tmp_path / "out.yaml"}
    before = sorted(p.name for p in tmp_path.iterdir())
    argv = ["rig"] + [a.format(**paths) for a in args]
    if args[0] == "import":
        argv += ["--out", str(tmp_path / "new.rig.json")]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and err.startswith("camcal: error:")
    assert np.any([m in err for m in message.split("|")]), err
    assert sorted(p.name for p in tmp_path.iterdir()) == before
