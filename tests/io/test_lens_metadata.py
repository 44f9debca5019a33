"""The lens metadata CSV: each frame's focal length and focus distance (or encoders), every bad row one line."""

from __future__ import annotations

import math

import numpy as np
import pytest

from camcal.base.errors import CamcalError
from camcal.io.lens_metadata import read_lens_metadata


def test_states_and_encoders_are_read_in_frame_order(tmp_path):
    path = tmp_path / "lens.csv"
    path.write_text("frame,focal_mm,focus_m\n11,35.5,inf\n10,35,2.5\n\n12,36,2.25\n")
    table = read_lens_metadata(path)
    assert table.frames.tolist() == [10, 11, 12] and not table.encoders
    np.testing.assert_array_equal(table.focal, [35.0, 35.5, 36.0])
    assert table.focus[0] == 2.5 and math.isinf(table.focus[1])
    path.write_text("frame,focal,focus\n0,0.25,1\n1,0.5,0.75\n")
    table = read_lens_metadata(path, encoders=True)
    assert table.encoders and table.focal.tolist() == [0.25, 0.5] and table.focus.tolist() == [1.0, 0.75]


@pytest.mark.parametrize("text, encoders, message", [
    ("frame,focal,focus\n0,0.5,0.5\n", False, "expected the header frame,focal_mm,focus_m (encoder values 0-1"),
    ("frame,focal_mm,focus_m\n0,35,2\n", True, "expected the header frame,focal,focus, got"),
    ("frame,focal_mm,focus_m\n0,35\n", False, "line 2: expected 3 values"),
    ("frame,focal_mm,focus_m\n-1,35,2\n", False, "line 2: the frame must be a whole number from 0"),
    ("frame,focal_mm,focus_m\n0,35,2\n0,36,2\n", False, "line 3: frame 0 is given twice"),
    ("frame,focal_mm,focus_m\n0,wide,2\n", False, "line 2: focal_mm must be a number, got 'wide'"),
    ("frame,focal_mm,focus_m\n0,inf,2\n", False, "line 2: focal_mm is not a finite number"),
    ("frame,focal,focus\n0,0.5,inf\n", True, "line 2: focus is not a finite number"),
    ("frame,focal_mm,focus_m\n0,35,2\n3,35,2\n", False, "frames 0-3 miss 2 frame(s): 1, 2"),
    ("frame,focal_mm,focus_m\n", False, "no frames"),
])
def test_a_bad_file_is_one_line_naming_it(tmp_path, text, encoders, message):
    path = tmp_path / "lens.csv"
    path.write_text(text)
    with pytest.raises(CamcalError, match="lens.csv") as raised:
        read_lens_metadata(path, encoders=encoders)
    assert message in str(raised.value) and "\n" not in str(raised.value)
