"""`calibrate board` on videos of a ring of cameras around a two-sided chessboard (seen from both sides)."""

import sys
from pathlib import Path

import numpy as np
import pytest

from camcal.cli import main
from camcal.geometry.board import parse_board
from camcal.model.camera import rotation_angle_deg
from camcal.model.rig import Rig

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "geometry"))
from capture_volume import make_volume, write_videos  # noqa: E402

SPEC = "chessboard:8x5:0.05:two-sided"


@pytest.mark.slow
def test_two_sided_chessboard_ring_from_videos(tmp_path, monkeypatch, capsys):
    board = parse_board(SPEC)
    volume = make_volume(6, 30, seed=4)
    paths, seen = write_videos(board, volume, tmp_path)
    Rig(tuple(volume.cameras)).save(tmp_path / "intr.rig.json")
    monkeypatch.chdir(tmp_path)
    cameras = [f"--images=cam{k}=cam_{k}.mp4" for k in range(len(paths))]
    code = main(["calibrate", "board", "--board", SPEC, *cameras, "--intrinsics", "intr.rig.json",
                 "--holdout", "1-29x3", "--out", "rig.rig.json"])
    out = capsys.readouterr().out
    assert code == 0, out
    rig, ref = Rig.load("rig.rig.json"), volume.cameras[0]
    rotation = max(rotation_angle_deg(c.R @ (t.R @ ref.R.T).T) for c, t in zip(rig.cameras, volume.cameras))
    centre = max(float(np.linalg.norm(c.c - ref.R @ (t.c - ref.c))) for c, t in zip(rig.cameras, volume.cameras))
    relabelled = [line for line in out.splitlines() if "relabelled (mirrored" in line]
    with capsys.disabled():
        print(f"\n{relabelled[0][:120]}...\nworst rotation {rotation:.4f} deg, worst centre {centre * 1e3:.3f} mm "
              f"({100 * centre / volume.size_m:.4f} % of {volume.size_m:.1f} m)")
    assert relabelled and rotation < 0.05 and centre < 1e-3 * volume.size_m
