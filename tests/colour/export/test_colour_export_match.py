"""Camera matches (kind ``match``) exported as OCIO Looks, checked through OCIO's own processor."""

import numpy as np
import pytest

ocio = pytest.importorskip("PyOpenColorIO")

import colour  # noqa: E402

from camcal.cli import main  # noqa: E402
from camcal.colour.difference import delta_E  # noqa: E402
from camcal.colour.export.ocio_config import CAMCAL_BASE  # noqa: E402
from camcal.io.ocio import export_ocio  # noqa: E402
from camcal.colour.export.ocio_fit import look_name  # noqa: E402
from camcal.colour.match.record import ColourMatch  # noqa: E402
from camcal.colour.match.robust import fit_match_model  # noqa: E402
from camcal.io.colourfile import save_colour_file

M_TRUE = np.array([[1.10, -0.08, 0.03], [0.05, 0.93, 0.04], [-0.02, 0.09, 0.88]])


def curved(B):
    """A smooth non-linear camera-to-camera map (the truth a root-polynomial / LUT must follow)."""
    return np.maximum(B @ M_TRUE.T, 0.0) ** 1.05 + 0.02 * np.sqrt(B[:, [1, 2, 0]] * B[:, [2, 0, 1]])


def make_match(model, target=lambda B: B @ M_TRUE.T):
    B = np.random.default_rng(0).uniform(0.02, 1.0, (2000, 3))
    fit = fit_match_model(B, target(B), model, robust="none")
    stats = {"n": 2000, "mean": 0.0, "median": 0.0, "p90": 0.0, "p95": 0.0, "max": 0.0}
    return ColourMatch(model=fit.model, evaluation={"metric": "CIE 2000", "space": "linear Rec. 709", "train": stats,
                                                    "test": None, "before": None, "n_test_outliers": None,
                                                    "chart": None},
                       fit={"route": "image", "robust": "none", "n_fit": 2000, "n_inliers": 2000,
                            "inlier_threshold": None},
                       source="right", target="left")


def through_look(config_path, look, RGB):
    config = ocio.Config.CreateFromFile(str(config_path))
    data = config.getRoleColorSpace(ocio.ROLE_DATA)
    transform = ocio.LookTransform(src=data, dst=data, looks=look)
    cpu = config.getProcessor(transform).getDefaultCPUProcessor()
    out = np.ascontiguousarray(RGB, dtype=np.float32).copy()
    cpu.applyRGB(out)
    return out.astype(np.float64)


def test_matrix_match_look_is_exact(tmp_path):
    match = make_match("matrix3x3")
    result = export_ocio([], tmp_path / "ocio", base=CAMCAL_BASE, matches=[match])
    RGB = np.random.default_rng(1).uniform(0.0, 1.0, (500, 3))
    got = through_look(result.config_path, look_name("right", "left"), RGB)
    assert np.max(np.abs(got - match.apply(RGB))) < 1e-5
    assert np.max(np.abs(got - RGB @ M_TRUE.T)) < 1e-4  # and the fit found the true matrix


@pytest.mark.parametrize("model", ["root-polynomial:2", "lut3d:9"])
def test_nonlinear_match_look_is_baked_within_delta_E(tmp_path, model):
    match = make_match(model, curved)
    result = export_ocio([], tmp_path / "ocio", base=CAMCAL_BASE, matches=[match])
    (report,) = result.spaces
    assert report.bake_error.max < 0.2 and (tmp_path / "ocio" / report.clf).is_file()
    RGB = np.random.default_rng(2).uniform(0.05, 1.0, (2000, 3))
    got = through_look(result.config_path, look_name("right", "left"), RGB)
    rec709 = colour.RGB_COLOURSPACES["ITU-R BT.709"]
    white = colour.xy_to_XYZ(rec709.whitepoint)
    error = delta_E(got @ rec709.matrix_RGB_to_XYZ.T, match.apply(RGB) @ rec709.matrix_RGB_to_XYZ.T, white)
    assert np.mean(error) < 0.1 and np.percentile(error, 95) < 0.2


def test_cli_exports_a_match_and_refuses_icc(tmp_path):
    path = save_colour_file(make_match("matrix3x3"), tmp_path / "m.colour.json")
    assert main(["colour", "export", str(path), "--ocio", str(tmp_path / "cfg"), "--base", "camcal"]) == 0
    config = ocio.Config.CreateFromFile(str(tmp_path / "cfg" / "config.ocio"))
    assert config.getLook(look_name("right", "left")) is not None
    assert main(["colour", "export", str(path), "--icc", str(tmp_path / "m.icc")]) == 2
    assert not (tmp_path / "m.icc").exists()
