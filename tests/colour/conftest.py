"""Simulated camera data shared by the colour tests.

Nikon 5100 (NPL) sensitivities from colour-science under CIE D65, 0.2 %
multiplicative noise; training: ColorChecker 24 (BabelColor Average
spectra); independent: the 190 RAW-to-ACES training reflectances.
"""

from dataclasses import dataclass

import numpy as np
import pytest

from camcal.colour.spectral import SimulatedCamera, reflectance_set

NOISE = 0.002


@dataclass
class SimData:
    camera: SimulatedCamera
    RGB_train: np.ndarray
    XYZ_train: np.ndarray
    names_train: list
    RGB_test: np.ndarray
    XYZ_test: np.ndarray
    names_test: list
    white: np.ndarray


def make_sim(camera="Nikon 5100 (NPL)", illuminant="D65", seed=0) -> SimData:
    cam = SimulatedCamera.from_colour(camera, illuminant)
    names_cc, R_cc = reflectance_set("BabelColor Average", cam.wavelengths)
    names_ind, R_ind = reflectance_set("rawtoaces 190", cam.wavelengths)
    return SimData(
        cam,
        cam.RGB(R_cc, NOISE, seed), cam.XYZ(R_cc), names_cc,
        cam.RGB(R_ind, NOISE, seed + 100), cam.XYZ(R_ind), names_ind,
        cam.white_XYZ,
    )


@pytest.fixture(scope="session")
def sim() -> SimData:
    return make_sim()


@pytest.fixture(scope="session")
def sim_factory():
    """``make_sim(camera, illuminant, seed)`` for other cameras and scenes."""
    return make_sim
