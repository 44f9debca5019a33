"""solve's track refinement: on with the sequential matcher, its observations in the model it writes."""

from pathlib import Path

import numpy as np
import pytest

from camcal.base.errors import CamcalError
from camcal.geometry.bundle import state_from_reconstruction
from camcal.model.camera import pixels_from_colmap
from camcal.pipelines.solve import solve_sfm
from camcal.synthetic import render_stereo_sequence

pycolmap = pytest.importorskip("pycolmap")


@pytest.fixture(scope="module")
def plate(tmp_path_factory):
    """Six frames of one camera of a rendered stereo sequence: the folder of its PNG files."""
    root = tmp_path_factory.mktemp("tracks")
    width = 256
    focal, height = 500.0 * width / 640, width * 3 // 4
    render_stereo_sequence(root, n_frames=6, image_size=(width, height),
                           K=((focal, 0.0, (width - 1) / 2), (0.0, focal, (height - 1) / 2), (0.0, 0.0, 1.0)))
    return root / "left"


def _solve(plate: Path, out: Path, matcher: str, tracks: str = "auto") -> list[str]:
    lines: list[str] = []
    solve_sfm({"left": plate}, out, matcher=matcher, tracks=tracks, max_num_features=1024, jackknife=None,
              progress=lines.append)
    return lines


def _detected_and_modelled(out: Path) -> tuple[np.ndarray, np.ndarray]:
    """Every observation of the written model: its keypoint as detected (the database) and as in the model."""
    model = pycolmap.Reconstruction(out / "sparse" / "best")
    database = pycolmap.Database.open(out / "database.db")
    try:
        detected, modelled = [], []
        for image_id, image in model.images.items():
            keypoints = database.read_keypoints(image_id)[:, :2]
            for index, point in enumerate(image.points2D):
                if point.has_point3D():
                    detected.append(keypoints[index])
                    modelled.append(point.xy)
    finally:
        database.close()
    return np.array(detected), np.array(modelled)


def test_a_sequential_solve_refines_its_tracks_and_writes_them_into_its_model(plate, tmp_path):
    """auto with the sequential matcher: the line says how many observations moved; the model written holds
    them (the rest as detected; the outlier rejection after the refinement drops a few), and reading the model
    gives the same observations back."""
    lines = _solve(plate, tmp_path / "out", "sequential")
    line = next(line for line in lines if line.startswith("tracks refined: "))
    detected, modelled = _detected_and_modelled(tmp_path / "out")
    moved = np.linalg.norm(modelled - detected, axis=1) > 0
    refined = int(line.split()[2])
    assert 0.8 * refined < moved.sum() <= refined and moved.mean() > 0.5 and np.all(np.linalg.norm(modelled - detected, axis=1) < 1.0)
    state = state_from_reconstruction(pycolmap.Reconstruction(tmp_path / "out" / "sparse" / "best"))
    assert np.array_equal(state.obs_xy, pixels_from_colmap(modelled))


def test_an_exhaustive_solve_keeps_the_detected_keypoints(plate, tmp_path):
    lines = _solve(plate, tmp_path / "out", "exhaustive")
    assert not any(line.startswith("tracks refined") for line in lines)
    detected, modelled = _detected_and_modelled(tmp_path / "out")
    assert np.array_equal(detected, modelled)


def test_an_unknown_track_mode_is_one_error_and_nothing_is_written(plate, tmp_path):
    with pytest.raises(CamcalError, match="unknown track mode 'aligned', expected one of: auto, refine, detected"):
        _solve(plate, tmp_path / "out", "sequential", tracks="aligned")
    assert not (tmp_path / "out").exists()
