"""Simulated cameras: reflectances through measured sensitivities under an illuminant.

:class:`SimulatedCamera` renders reflectances through measured camera
sensitivities (colour-science's ``MSDS_CAMERA_SENSITIVITIES``) under an
illuminant (``SDS_ILLUMINANTS``) and the CIE 1931 observer, giving camera
RGB and reference XYZ for characterisation tests with ground truth. Camera
RGB is linear, normalised so the perfect white (reflectance 1) gives G = 1;
XYZ is relative with Y = 1 for the perfect white.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from camcal.base.errors import CamcalError
from camcal.base.extras import require
from camcal.colour.spectral.data import CMFS_NAME, camera_sensitivities, reflectance_XYZ, resample_spectral, spectral_shape

__all__ = ["SimulatedCamera"]


@dataclass(frozen=True, eq=False)
class SimulatedCamera:
    """A camera with known spectral sensitivities under a known illuminant.

    Attributes
    ----------
    wavelengths
        ``(W,)`` nm.
    sensitivities
        ``(W, 3)`` camera R, G, B sensitivities.
    illuminant
        ``(W,)`` spectral power of the scene illuminant.
    cmfs
        ``(W, 3)`` CIE 1931 colour matching functions.
    name, illuminant_name
        Labels.
    """

    wavelengths: np.ndarray
    sensitivities: np.ndarray
    illuminant: np.ndarray
    cmfs: np.ndarray
    name: str = ""
    illuminant_name: str = ""

    @classmethod
    def from_colour(cls, camera: str = "Nikon 5100 (NPL)", illuminant: str = "D65") -> SimulatedCamera:
        """One of colour-science's measured cameras under a CIE illuminant."""
        colour = require("colour")

        wavelengths, sens = camera_sensitivities(camera)
        if illuminant not in colour.SDS_ILLUMINANTS:
            raise CamcalError(f"unknown illuminant {illuminant!r}, expected a name of colour.SDS_ILLUMINANTS")
        S = resample_spectral(colour.SDS_ILLUMINANTS[illuminant], wavelengths)
        cmfs = resample_spectral(colour.MSDS_CMFS[CMFS_NAME], wavelengths)
        return cls(wavelengths, sens, S, cmfs, camera, illuminant)

    @property
    def exposure(self) -> float:
        """Factor making the perfect white's G equal to 1."""
        return 1.0 / float(self.illuminant @ self.sensitivities[:, 1])

    def stimulus(self, reflectances: Any) -> np.ndarray:
        """Reflectances times the illuminant, ``(N, W)``."""
        R = np.atleast_2d(np.asarray(reflectances, dtype=np.float64))
        if R.shape[-1] != self.wavelengths.size:
            raise CamcalError(
                f"reflectances have {R.shape[-1]} samples, the camera grid has {self.wavelengths.size}"
            )
        return R * self.illuminant[None, :]

    def RGB(self, reflectances: Any, noise: float = 0.0, seed: int | None = 0) -> np.ndarray:
        """Linear camera RGB, white G = 1, with optional relative noise.

        ``noise`` is the standard deviation of a multiplicative Gaussian
        error (0.002 for 0.2 %), independent per patch and channel.
        """
        RGB = self.stimulus(reflectances) @ self.sensitivities * self.exposure
        if noise:
            rng = np.random.default_rng(seed)
            RGB = RGB * (1.0 + noise * rng.standard_normal(RGB.shape))
        return RGB

    def XYZ(self, reflectances: Any) -> np.ndarray:
        """Relative XYZ under the scene illuminant, perfect white Y = 1."""
        R = self.stimulus(reflectances) / self.illuminant[None, :]  # checked against the camera grid
        shape = spectral_shape(self.wavelengths)
        return reflectance_XYZ(R, self.illuminant, (shape.start, shape.end, shape.interval))[0]

    @property
    def white_XYZ(self) -> np.ndarray:
        return self.XYZ(np.ones(self.wavelengths.size))[0]

    @property
    def RGB_white(self) -> np.ndarray:
        return self.RGB(np.ones(self.wavelengths.size))[0]

    @property
    def effective_sensitivities(self) -> np.ndarray:
        """Sensitivities in the units of :meth:`RGB`: ``RGB = (R * S) @ this``."""
        return self.sensitivities * self.exposure
