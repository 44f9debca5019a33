"""``solve --readout-ms``: the readout time asked for, and bad values one error each before any work."""

import pytest

from camcal.base.errors import CamcalError
from camcal.cli import main
from camcal.pipelines.solve_shutter import TYPICAL_READOUT_MS, ShutterSpec, shutter_spec


def test_a_readout_is_milliseconds_typical_or_estimate_and_none_is_no_check():
    assert shutter_spec(None) is None
    assert shutter_spec(" Estimate ") == ShutterSpec(None, 1.0, None)
    assert shutter_spec("typical") == ShutterSpec(TYPICAL_READOUT_MS, 1.0, None) and TYPICAL_READOUT_MS == 30.0
    assert shutter_spec("12.5", 2.0, 29.97) == ShutterSpec(12.5, 2.0, 29.97)


@pytest.mark.parametrize("readout, threshold, fps, message", [
    ("fast", 1.0, None, "must be a number of milliseconds, 'typical' or 'estimate', got 'fast'"),
    (-3.0, 1.0, None, "must be a positive number of milliseconds, got -3.0"),
    (30.0, 0.0, None, "threshold must be a positive number of pixels, got 0.0"),
    (30.0, 1.0, float("nan"), "frame rate must be a positive number of frames per second, got nan"),
])
def test_bad_readout_threshold_or_rate_is_one_error(readout, threshold, fps, message):
    with pytest.raises(CamcalError, match=message):
        shutter_spec(readout, threshold, fps)


@pytest.mark.parametrize("option", [["--fps", "25"], ["--readout-flag-px", "2"]])
def test_rate_and_threshold_without_a_readout_are_a_usage_error_and_nothing_is_written(tmp_path, capsys, option):
    assert main(["solve", str(tmp_path), *option, "--out", str(tmp_path / "out")]) == 2
    assert f"{option[0]} has no effect without --readout-ms" in capsys.readouterr().err
    assert not (tmp_path / "out").exists()


def test_a_bad_readout_on_the_command_line_is_one_line_and_nothing_is_written(tmp_path, capsys):
    (tmp_path / "in").mkdir()
    assert main(["solve", str(tmp_path / "in"), "--readout-ms", "fast", "--out", str(tmp_path / "out")]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["camcal: error: the readout time must be a number of milliseconds, 'typical' or 'estimate', got "
                   "'fast'"]
    assert not (tmp_path / "out").exists()


def test_frames_without_distinct_numbers_are_timed_by_their_order_and_said():
    """Photographs named without frame numbers (or two alike) cannot be timed by number: the rig's frame order is
    used, one frame interval apart, and the line says so; the same cameras and points then give the same
    displacements as frames numbered 0, 1, 2."""
    import numpy as np

    from camcal.model.camera import look_at
    from camcal.model.distortion import Distortion
    from camcal.model.rig import Camera, Frame, Rig
    from camcal.pipelines.solve_shutter import check_rolling_shutter

    class _Point:
        def __init__(self, point_id):
            self.point3D_id = point_id

        def has_point3D(self):
            return True

    class _Model:
        """A reconstruction's answer to what each image observes: every point, in every image."""

        def __init__(self, xyz):
            self.points3D = {k: type("P", (), {"xyz": p})() for k, p in enumerate(xyz)}

        def find_image_with_name(self, name):
            return type("I", (), {"points2D": [_Point(k) for k in self.points3D]})()

    camera = Camera("cam", (640, 360), [[500.0, 0, 319.5], [0, 500.0, 179.5], [0, 0, 1]], Distortion("none", {}),
                    np.eye(3), np.zeros(3))
    centres = [np.array([0.0, 0.3 * k, 0.0]) for k in range(3)]
    xyz = np.random.default_rng(1).uniform([-3, 5, -2], [3, 20, 2], (50, 3))

    def rig(names):
        return Rig((camera,), frames=tuple(Frame(k, look_at(c, c + [0.1 * k, 1.0, 0.0]), c, {"cam": name})
                                           for k, (c, name) in enumerate(zip(centres, names))))

    spec = ShutterSpec(30.0, 0.5, 24.0)
    numbered, numbered_lines = check_rolling_shutter(_Model(xyz), rig(["a0.png", "a1.png", "a2.png"]),
                                                     {f"a{k}.png": f"cam/{k}" for k in range(3)}, spec, 1 / 24, 24.0)
    names = ["left.png", "right.png", "top.png"]
    ordered, lines = check_rolling_shutter(_Model(xyz), rig(names), {name: name for name in names}, spec, 1 / 24,
                                           24.0)
    assert "timed by their order" in lines[0] and "timed by their order" not in numbered_lines[0]
    for a, b in zip(numbered.frames, ordered.frames):
        assert a.rolling_shutter["cam"].displacement_px == b.rolling_shutter["cam"].displacement_px > 0.5


class _Observation:
    def __init__(self, xy, point_id):
        self.xy, self.point3D_id = xy, point_id

    def has_point3D(self):
        return True


class _Plate:
    """A reconstruction's answers for a synthetic rolling-shutter plate: each frame's observations (COLMAP's pixel
    centres at 0.5), the points and a real pycolmap lens to undistort them through."""

    def __init__(self, synthetic, lens, names):
        import numpy as np

        self.cameras = {1: lens}
        self.points3D = {int(k): type("P", (), {"xyz": xyz})() for k, xyz in enumerate(synthetic.points)}
        self.images = {}
        for k, name in enumerate(names):
            mine = np.flatnonzero(synthetic.frame_of == k)
            points2D = [_Observation(synthetic.pixels[m] + 0.5, int(synthetic.point_of[m])) for m in mine]
            self.images[name] = type("I", (), {"points2D": points2D, "camera_id": 1})()

    def find_image_with_name(self, name):
        return self.images.get(name)


def _solved_plate(motion):
    """A 12-frame plate read out in 25 ms through a lens with barrel distortion, as a solve leaves it."""
    import pycolmap
    from tests.geometry.rolling_shutter_plates import HEIGHT, K, WIDTH, plate

    from camcal.model.distortion import Distortion
    from camcal.model.rig import Camera, Frame, Rig

    lens = pycolmap.Camera(model="SIMPLE_RADIAL", width=WIDTH, height=HEIGHT, params=[K[0, 0], 320.0, 180.0, -0.05])
    synthetic = plate(0.025, motion, 7, lens=lens)
    names = [f"plate.{1001 + k:04d}.png" for k in range(len(synthetic.times))]
    camera = Camera("cam", (WIDTH, HEIGHT), K, Distortion("none", {}), [[1, 0, 0], [0, 1, 0], [0, 0, 1]], [0, 0, 0])
    rig = Rig((camera,), frames=tuple(Frame(k, R, c, {"cam": name}) for k, (R, c, name)
                                      in enumerate(zip(synthetic.rotations, synthetic.centres, names))))
    return _Plate(synthetic, lens, names), rig, {name: name for name in names}


def test_an_estimated_readout_is_stored_with_its_sigma_and_checks_the_frames():
    """A turning plate: the readout found through the solved lens lies within 3 sigma of the 25 ms it was read
    out in, is recorded with its sigma, and the frames carry the displacements the same readout given gives."""
    from camcal.pipelines.solve_shutter import check_rolling_shutter

    model, rig, names = _solved_plate("turning")
    estimated, lines = check_rolling_shutter(model, rig, names, ShutterSpec(None, 1.0, 30.0), 1 / 30, 30.0)
    record = estimated.provenance["rolling_shutter"]["estimate"]["cam"]
    # 12 frames, 800 observations: the jackknife's sigma (9 degrees of freedom) scatters by a quarter about the noise's
    assert record["determined"] and abs(record["readout_ms"] - 25.0) < 3.0 * record["sigma_ms"] < 4.5
    assert lines[0].startswith("rolling-shutter readout of cam estimated from the plate: ")
    assert record["sigma_ms"] == max(record["noise_sigma_ms"], record["jackknife_sigma_ms"])
    assert f"a jackknife over blocks of frames, {record['jackknife_sigma_ms']:.2f} ms" in lines[0]
    assert lines[1].startswith("rolling shutter (estimated readout at 30 fps, threshold 1 px): flagged cam frames")
    given, _ = check_rolling_shutter(model, rig, names, ShutterSpec(record["readout_ms"], 1.0, 30.0), 1 / 30, 30.0)
    for a, b in zip(estimated.frames, given.frames):
        assert a.rolling_shutter["cam"] == b.rolling_shutter["cam"]
    assert max(frame.rolling_shutter["cam"].displacement_px for frame in estimated.frames) > 5.0


def test_a_plate_that_does_not_determine_its_readout_says_so_and_checks_nothing():
    from camcal.pipelines.solve_shutter import check_rolling_shutter

    model, rig, names = _solved_plate("sideways")
    checked, lines = check_rolling_shutter(model, rig, names, ShutterSpec(None, 1.0, 30.0), 1 / 30, 30.0)
    record = checked.provenance["rolling_shutter"]["estimate"]["cam"]
    assert not record["determined"] and "readout_ms" not in record and record["sigma_ms"] > record["limit_ms"]
    assert len(lines) == 1 and "the plate's motion does not determine it" in lines[0]
    assert all(not frame.rolling_shutter for frame in checked.frames)


def test_a_plate_too_short_to_estimate_from_says_so_and_checks_nothing():
    import dataclasses

    from camcal.pipelines.solve_shutter import check_rolling_shutter

    model, rig, names = _solved_plate("turning")
    short = dataclasses.replace(rig, frames=rig.frames[:2])
    checked, lines = check_rolling_shutter(model, short, names, ShutterSpec(None, 1.0, 30.0), 1 / 30, 30.0)
    assert lines == ["rolling-shutter readout of cam: cannot be estimated (estimating a readout time needs at least 3 "
                     "solved frames, got 2), so its frames are not checked; give --readout-ms"]
    assert checked.provenance["rolling_shutter"]["estimate"]["cam"]["determined"] is False
    assert all(not frame.rolling_shutter for frame in checked.frames)
