"""``solve --up --origin --scale --units``: the world of a solved plate set on its ground, against the rendered truth."""

import json

import numpy as np
import pytest

from camcal.base.errors import CamcalError
from camcal.cli import main
from camcal.io.ply import read_points_ply
from camcal.model.camera import chordal_mean_rotation
from camcal.model.distortion import Distortion
from camcal.model.rig import Camera, Rig
from camcal.pipelines.solve_world import world_spec
from camcal.synthetic import render_stereo_sequence

WIDTH, HEIGHT = 256, 192
FOCAL = 500.0 * WIDTH / 640
K = ((FOCAL, 0.0, (WIDTH - 1) / 2), (0.0, FOCAL, (HEIGHT - 1) / 2), (0.0, 0.0, 1.0))


def test_the_world_of_a_rendered_plate_is_set_on_its_floor_with_the_scale_given(tmp_path, capsys):
    """The rendered room's floor is z = 0 with +z up: after --up ground the solved +z is the truth's (to the
    solve's noise), the floor's points lie at z = 0, the first camera stands over the origin looking down +y, and
    the two points given are the distance given apart, in the units given."""
    truth = render_stereo_sequence(tmp_path / "in", n_frames=4, image_size=(WIDTH, HEIGHT),
                                   K=K)
    code = main(["solve", str(tmp_path / "in" / "left"), "--features", "512", "--model", "polynomial",
                 "--uncertainty", "covariance",
                 "--up", "ground", "--origin", "ground", "--scale", "0,1=2.5", "--units", "ft",
                 "--out", str(tmp_path / "out"), "--json"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    notes = json.loads(captured.out)["figures"]["notes"]
    assert [note.split(":")[0] for note in notes] == ["ground plane", "up", "origin", "scale"]
    rig = Rig.load(tmp_path / "out" / "solve.rig.json")
    assert rig.units == "ft"
    points = read_points_ply(tmp_path / "out" / rig.points)
    xyz = np.column_stack([points["x"], points["y"], points["z"]])
    assert abs(np.linalg.norm(xyz[1] - xyz[0]) - 2.5) < 1e-9
    solved = [rig.camera_at_frame("left", frame.index) for frame in rig.frames]
    assert np.linalg.norm(solved[0].c[:2]) < 1e-9 and solved[0].c[2] > 0  # over the origin, above the ground
    view = solved[0].R[2]
    assert abs(view[0]) < 1e-9 and view[1] > 0  # looking down +y
    Q = chordal_mean_rotation([truth["left", k].R.T @ camera.R for k, camera in enumerate(solved)])
    assert np.degrees(np.arccos(min(1.0, (Q @ [0, 0, 1])[2]))) < 2.0  # the solved +z is the truth's up (1.0 deg)
    n_floor = int(np.sum(np.abs(xyz[:, 2]) < 0.01 * np.ptp(xyz[:, 2])))
    assert n_floor > 30  # the floor's points at z = 0


@pytest.mark.parametrize(("options", "message"), [
    (dict(scale="1,2"), "expected A,B=DISTANCE"),
    (dict(scale="1,2=-3"), "distance must be positive"),
    (dict(scale="1,x=3"), "a point is its row in points.ply"),
    (dict(origin="1:2"), "a point is its row in points.ply"),
    (dict(up="sky"), "unknown --up 'sky'"),
    (dict(units="m"), "give --scale too"),
])
def test_world_options_that_cannot_be_read_are_one_error_before_any_work(options, message):
    with pytest.raises(CamcalError, match=message):
        world_spec(**options)


def test_world_options_are_read_as_points_rows_or_coordinates():
    spec = world_spec(up="cameras", origin="-0.5:1e-3:2", scale="12,1.5:-2:0.25=1.5")
    assert spec.up == "cameras" and spec.units == "m" and spec.active
    np.testing.assert_array_equal(spec.origin, [-0.5, 1e-3, 2.0])
    assert spec.scale[0] == 12 and np.array_equal(spec.scale[1], [1.5, -2.0, 0.25]) and spec.scale[2] == 1.5
    assert world_spec(origin="ground").origin == "ground" and not world_spec().active


def test_the_cli_refuses_units_without_scale_and_a_point_the_solve_does_not_have(tmp_path, capsys):
    render_stereo_sequence(tmp_path / "in", n_frames=3, image_size=(WIDTH, HEIGHT),
                           K=K)
    assert main(["solve", str(tmp_path / "in" / "left"), "--units", "m", "--out", str(tmp_path / "out")]) == 2
    assert "--units has no effect without --scale" in capsys.readouterr().err
    code = main(["solve", str(tmp_path / "in" / "left"), "--features", "512", "--no-refine",
                 "--origin", "99999", "--out", str(tmp_path / "out")])
    err = capsys.readouterr().err
    assert code == 2 and "--origin: point 99999 does not exist: the solve has" in err
    assert not (tmp_path / "out").exists()


def test_the_api_and_the_cli_refuse_the_same_world_and_lens_options(tmp_path, capsys):
    """camcal.solve takes the command's new options under the same names and says the same line, before any work."""
    import camcal
    from tests.test_api import assert_same_error

    render_stereo_sequence(tmp_path / "in", n_frames=2, image_size=(WIDTH, HEIGHT),
                           K=K)
    folder, out = tmp_path / "in" / "left", tmp_path / "o"
    Rig((Camera("cam", (WIDTH, HEIGHT), np.array(K), Distortion.none(), np.eye(3), np.zeros(3)),)).save(
        tmp_path / "grid.rig.json")
    for api_call, argv in [
        (lambda: camcal.solve(folder, out, scale="3,4"), ["solve", folder, "--scale", "3,4", "--out", out]),
        (lambda: camcal.solve(folder, out, origin="a:b:c"), ["solve", folder, "--origin=a:b:c", "--out", out]),
        (lambda: camcal.solve(folder, out, intrinsics=tmp_path / "grid.rig.json", model="division"),
         ["solve", folder, "--intrinsics", tmp_path / "grid.rig.json", "--model", "division", "--out", out]),
        (lambda: camcal.solve(folder, out, intrinsics=tmp_path / "grid.rig.json", intrinsics_mode="prior"),
         ["solve", folder, "--intrinsics", tmp_path / "grid.rig.json", "--intrinsics-mode", "prior", "--out", out]),
    ]:
        assert_same_error(api_call, argv, capsys)
    assert not out.exists()
