"""Colours synthesised through sensitivities estimated from the chart itself: held-out colours and a spectral training set.

A ColorChecker's 24 patches are few for choosing a model or training a
non-linear one. With the chart's spectra known (colour-science's
``BabelColor Average`` and the like, matched by patch name), the camera's
sensitivities are estimated from the chart's own linear captures
(:func:`camcal.colour.spectral.captures.estimate_from_captures`: positivity,
smoothness, cross-validated), and two large reflectance sets no fit step
otherwise sees are rendered through them under the chart's illuminant, the
way an ACES IDT is built from spectral data (ACES P-2013-001, ISO 17321-1):

- :data:`SYNTHETIC_TRAINING` (``CIE 2017 TCS``, the 99 measured colour
  evaluation samples of CIE 224:2017, and ``Munsell validation``, 300
  Munsell colours): the spectral route's training colours, beside the
  chart's own captures kept as anchors. The measured samples bring the
  spectral shapes of real surfaces (skins, foliage, textiles, prints) that
  smooth reflectances recovered from Munsell chromaticities lack;
- :data:`SYNTHETIC_HELD_OUT` (``Munsell held-out``, 300 other Munsell
  colours): the held-out colours ``auto`` scores its candidates on
  (:mod:`camcal.colour.fit.select`).

The rendered RGB are scaled per channel to the chart's units (least squares
of the chart's captures against the same patches rendered through the
estimate), XYZ are relative to the illuminant's white (Y = 1).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from camcal.base.errors import CamcalError
from camcal.colour.chart.patches import PatchSet
from camcal.colour.spectral.captures import Capture, chart_reflectances, estimate_from_captures
from camcal.colour.spectral.data import reflectance_XYZ, reflectance_set
from camcal.colour.spectral.sensitivities import DEFAULT_WAVELENGTHS, Sensitivities, illuminant_spd

__all__ = ["SYNTHETIC_TRAINING", "SYNTHETIC_HELD_OUT", "SyntheticSets", "synthesise_from_chart"]

SYNTHETIC_TRAINING = ("CIE 2017 TCS", "Munsell validation")
SYNTHETIC_HELD_OUT = "Munsell held-out"
_GRID = (360.0, 780.0, 5.0)


@dataclass(frozen=True, eq=False)
class SyntheticSets:
    """Sensitivities estimated from the chart and the two reflectance sets rendered through them."""

    sensitivities: Sensitivities
    training: PatchSet
    held_out: PatchSet
    gains: np.ndarray
    chart_rms: float

    def describe(self) -> str:
        return (f"sensitivities estimated from the chart's {self.sensitivities.estimation['captures'][0]['n_patches']}"
                f" patches (chart RGB reproduced to {100 * self.chart_rms:.2f} % RMS); training "
                f"{len(self.training)} ({' + '.join(SYNTHETIC_TRAINING)}), held out {len(self.held_out)} ({SYNTHETIC_HELD_OUT})")


def _rendered(sets: tuple[str, ...], sens: Sensitivities, illuminant: str, gains: np.ndarray) -> PatchSet:
    grid = np.arange(_GRID[0], _GRID[1] + 1, _GRID[2])
    on_grid = [reflectance_set(name, grid) for name in sets]
    names = [n for set_names, _ in on_grid for n in set_names]
    R = np.vstack([values for _, values in on_grid])
    XYZ, _ = reflectance_XYZ(R, illuminant_spd(illuminant, grid), _GRID)
    R_cam = np.vstack([reflectance_set(name, sens.wavelengths)[1] for name in sets])
    return PatchSet(tuple(names), sens.camera_under(illuminant).RGB(R_cam) * gains, XYZ)


def synthesise_from_chart(train: PatchSet, spectra: str, illuminant: str,
                          wavelengths: Any = DEFAULT_WAVELENGTHS) -> SyntheticSets:
    """Estimate sensitivities from a chart capture and render the training and held-out sets.

    Parameters
    ----------
    train
        The chart's patches: LINEAR camera RGB (any exposure), names matching ``spectra``.
    spectra
        colour-science's ColorChecker spectral data (``BabelColor Average``...).
    illuminant
        CIE name of the chart's light (colour-science ``SDS_ILLUMINANTS``).
    """
    wavelengths = np.asarray(wavelengths, dtype=np.float64)
    R = chart_reflectances(train.names, spectra, wavelengths)
    if len(train) < 10:
        raise CamcalError(f"the spectral route needs at least 10 patches, got {len(train)}")
    capture = Capture(train.names, R, train.RGB, illuminant_spd(illuminant, wavelengths), illuminant, "chart")
    sens = estimate_from_captures([capture], wavelengths)
    rendered = sens.camera_under(illuminant).RGB(R)
    gains = np.sum(rendered * train.RGB, axis=0) / np.sum(rendered**2, axis=0)
    chart_rms = float(np.sqrt(np.mean((rendered * gains - train.RGB) ** 2) / np.mean(train.RGB**2)))
    return SyntheticSets(sens, _rendered(SYNTHETIC_TRAINING, sens, illuminant, gains),
                         _rendered((SYNTHETIC_HELD_OUT,), sens, illuminant, gains), gains, chart_rms)
