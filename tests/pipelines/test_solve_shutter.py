"""``solve --readout-ms``: the readout time asked for, and bad values one error each before any work."""

import pytest

from camcal.base.errors import CamcalError
from camcal.cli import main
from camcal.pipelines.solve_shutter import TYPICAL_READOUT_MS, ShutterSpec, shutter_spec


def test_a_readout_is_milliseconds_or_typical_and_none_is_no_check():
    assert shutter_spec(None) is None
    assert shutter_spec("typical") == ShutterSpec(TYPICAL_READOUT_MS, 1.0, None) and TYPICAL_READOUT_MS == 30.0
    assert shutter_spec("12.5", 2.0, 29.97) == ShutterSpec(12.5, 2.0, 29.97)


@pytest.mark.parametrize("readout, threshold, fps, message", [
    ("fast", 1.0, None, "must be a number of milliseconds or 'typical', got 'fast'"),
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
    assert err == ["camcal: error: the readout time must be a number of milliseconds or 'typical', got 'fast'"]
    assert not (tmp_path / "out").exists()
