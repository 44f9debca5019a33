"""``model="auto"``'s fold fits in scoring mode (no covariance, no jackknife, no sigmas) against the full fit."""

import numpy as np
import pytest

from camcal.geometry import zhang_rank
from camcal.geometry.board import Board
from camcal.geometry.zhang_fit import calibrate_model
from camcal.geometry.zhang_rank import rank_models
from camcal.model.distortion import Distortion
from camcal.model.rig import Camera
from tests.geometry.test_zhang_models import views

BOARD = Board("chessboard", 9, 6, 0.03)
CAMERA = Camera("cam", (1280, 960), np.array([[900.0, 0, 641.5], [0, 902.0, 478.0], [0, 0, 1]]),
                Distortion("polynomial", {"k1": -0.12, "k2": 0.05}), np.eye(3), np.zeros(3))
OPTIONS = dict(units="m", outlier_factor=3.0, min_outlier_px=1.0, loss="trivial", loss_scale=1.0)


@pytest.mark.parametrize("model", ["polynomial", "kannala-brandt", "opencv"])
def test_scoring_fold_fit_gives_the_full_fits_heldout_errors(model):
    """A fold of 3 of 12 synthetic views held out: the scoring fit's per-view held-out RMS, its lens and its
    training RMS equal the full fit's to 1e-6 px, and it carries no covariance."""
    detections = views(CAMERA, BOARD, 12, np.random.default_rng(7), distance=(0.5, 0.8))["cam"]
    by_frame = [dict(enumerate(detections))]
    fold = {1, 5, 9}
    full = calibrate_model(BOARD, ["cam"], by_frame, model, fold, **OPTIONS)
    scoring = calibrate_model(BOARD, ["cam"], by_frame, model, fold, scoring=True, **OPTIONS)
    assert len(full.heldout_view_rms_px) == len(fold) and full.covariance.size > 0
    np.testing.assert_allclose(scoring.heldout_view_rms_px, full.heldout_view_rms_px, rtol=0, atol=1e-6)
    np.testing.assert_allclose(scoring.heldout_residuals_px, full.heldout_residuals_px, rtol=0, atol=1e-6)
    assert abs(scoring.rms_px - full.rms_px) < 1e-6
    rays = np.stack(np.meshgrid(np.linspace(-0.6, 0.6, 9), np.linspace(-0.45, 0.45, 7), [1.0]), axis=-1).reshape(-1, 3)
    np.testing.assert_allclose(scoring.rig.cameras[0].project(rays), full.rig.cameras[0].project(rays), atol=1e-6)
    assert scoring.covariance.size == 0 and "worst_projection_sigma_px" not in scoring.rig.cameras[0].quality.to_dict()


def test_ranking_with_shared_opencv_starts_scores_as_each_model_alone(monkeypatch):
    """The ranking shares OpenCV's model-free starts (the pinhole check, ``cv2.fisheye``'s) among the models of a
    fold: every model's held-out errors equal its fold fits made on their own. (The rational and thin-prism fits
    of ten views are ill-conditioned: two runs of the same fit differ by up to 1e-4 there, so they are left out; the others agree to 1e-6.)"""
    detections = views(CAMERA, BOARD, 10, np.random.default_rng(9), distance=(0.5, 0.8))["cam"]
    training = [dict(enumerate(detections))]
    fold_results: dict = {}
    monkeypatch.setattr(zhang_rank, "_screen", lambda *args: {})  # every model on the folds (no screen)
    ranking, squared, corners = rank_models(BOARD, ["cam"], training, OPTIONS, fold_results)
    compared = ("none", "division", "polynomial", "kannala-brandt", "opencv", "kannala-brandt-thin-prism")
    assert all(s.rms_px is not None for s in ranking if s.model in compared)
    for model in compared:
        alone = np.concatenate([calibrate_model(BOARD, ["cam"], training, model, fold, scoring=True,
                                           **OPTIONS).heldout_view_rms_px for fold in fold_results["folds"]])
        np.testing.assert_allclose(squared[model], np.square(alone) * corners, rtol=1e-6, atol=0, err_msg=model)
