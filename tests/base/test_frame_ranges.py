"""Frame ranges (``camcal batch --frames``, ``camcal calibrate board --holdout``)."""

import pytest

from camcal.base.errors import CamcalError
from camcal.base.frame_ranges import parse_frames


def test_parse_frames():
    assert parse_frames("1001-1005") == (1001, 1002, 1003, 1004, 1005)
    assert parse_frames("1-9x4") == (1, 5, 9)
    assert parse_frames("7, 3,2-4") == (2, 3, 4, 7)
    for bad in ("1240-1001", "abc", "1-5x0", "", "1001-"):
        with pytest.raises(CamcalError, match="frame range"):
            parse_frames(bad)
