"""Shared test fixtures: the real-image folder beside the project, simulated colour data."""

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

import pytest

SHARED_DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """`../shared/data`, or skip with the reason when a clone lacks it."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real test images not found at {SHARED_DATA}")
    return SHARED_DATA


@pytest.fixture
def real_pair_shots(shared_data, tmp_path) -> Path:
    """Real stereo pairs 02-07 (left/right JPEGs) copied into one folder ``tmp_path / "shots"``."""
    import shutil

    folder = tmp_path / "shots"
    folder.mkdir()
    for number in range(2, 8):
        for side in ("left", "right"):
            shutil.copy(shared_data / "stereo_chessboard" / f"{side}{number:02d}.jpg", folder)
    return folder


@pytest.fixture(autouse=True, scope="session")
def _corner_cache_in_a_temporary_folder(tmp_path_factory):
    """`calibrate board` caches corners under $XDG_CACHE_HOME: keep the tests' cache out of the user's."""
    previous = os.environ.get("XDG_CACHE_HOME")
    os.environ["XDG_CACHE_HOME"] = str(tmp_path_factory.mktemp("xdg_cache"))
    yield
    if previous is None:
        os.environ.pop("XDG_CACHE_HOME", None)
    else:
        os.environ["XDG_CACHE_HOME"] = previous


# -- simulated camera colour data (tests/colour) ------------------------------------

COLOUR_NOISE = 0.002


@dataclass
class SimData:
    camera: object
    RGB_train: np.ndarray
    XYZ_train: np.ndarray
    names_train: list
    RGB_test: np.ndarray
    XYZ_test: np.ndarray
    names_test: list
    white: np.ndarray


def make_sim(camera="Nikon 5100 (NPL)", illuminant="D65", seed=0) -> SimData:
    """Simulated camera data: Nikon 5100 (NPL) under D65 by default, 0.2 % noise;
    training ColorChecker 24 (BabelColor Average), independent: 190 RAW-to-ACES reflectances."""
    from camcal.colour.spectral.simulate import SimulatedCamera
    from camcal.colour.spectral.data import reflectance_set

    cam = SimulatedCamera.from_colour(camera, illuminant)
    names_cc, R_cc = reflectance_set("BabelColor Average", cam.wavelengths)
    names_ind, R_ind = reflectance_set("rawtoaces 190", cam.wavelengths)
    return SimData(
        cam,
        cam.RGB(R_cc, COLOUR_NOISE, seed), cam.XYZ(R_cc), names_cc,
        cam.RGB(R_ind, COLOUR_NOISE, seed + 100), cam.XYZ(R_ind), names_ind,
        cam.white_XYZ,
    )


@pytest.fixture(scope="session")
def sim() -> SimData:
    return make_sim()


@pytest.fixture(scope="session")
def sim_factory():
    """``make_sim(camera, illuminant, seed)`` for other cameras and scenes."""
    return make_sim
