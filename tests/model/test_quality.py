"""The typed fit quality of the rig file: documented keys, older files read."""

import numpy as np
import pytest

from camcal.base.errors import CamcalError
from camcal.model.quality import Quality
from camcal.model.rig import Camera, Rig
from camcal.synthetic import example_camera


def test_round_trip_and_mapping_view():
    q = Quality(rms_px=0.21, heldout_rms_px=0.25, n_views=18, n_observations=972,
                sigma={"fx": 0.4, "k1": 1e-4, "rotation_deg": 0.01, "baseline_rel": 1e-3})
    assert Quality.from_dict(q.to_dict()) == q
    assert q["sigma"]["fx"] == 0.4 and "worst_px" not in q and dict(q) == q.to_dict()
    assert not Quality() and Quality().to_dict() == {}


def test_board_and_solve_files_of_today_read_under_one_set_of_keys():
    """board wrote sigma fx/baseline (absolute), solve f/baseline_rel; both become the documented keys."""
    right = example_camera("right", centre=(0.6, -6.0, 1.4))
    length = float(np.linalg.norm(right.c))
    board = Camera(**{**right.__dict__, "quality": {"rms_px": 0.2, "n_points": 540,
                                                    "sigma": {"fx": 0.3, "baseline": 2e-3 * length, "rotation_deg": 0.02}}})
    solve = Camera(**{**right.__dict__, "quality": {"rms_px": 0.5, "n_observations": 9000,
                                                    "sigma": {"f": 0.7, "baseline_rel": 1e-3}}})
    assert board.quality.n_observations == 540
    assert board.quality.sigma["baseline_rel"] == pytest.approx(2e-3)
    assert set(board.quality.sigma) == {"fx", "baseline_rel", "rotation_deg"}
    assert solve.quality.sigma == {"fx": 0.7, "fy": 0.7, "baseline_rel": 1e-3}


@pytest.mark.parametrize("bad, message", [
    ({"rms": 0.2}, "unknown key 'rms'"),
    ({"rms_px": float("nan")}, "quality.rms_px must be a finite number >= 0"),
    ({"sigma": {"fx": -1.0}}, "quality.sigma.fx must be a finite number >= 0"),
    ({"n_views": 2.5}, "quality.n_views must be a count"),
    ({"sigma": [1, 2]}, "quality.sigma must be an object"),
])
def test_bad_quality_is_one_clear_error(bad, message, tmp_path):
    data = Rig((example_camera("a"),)).to_dict()
    data["cameras"][0]["quality"] = bad
    with pytest.raises(CamcalError, match=message):
        Rig.from_dict(data)
