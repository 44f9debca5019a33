"""Shared pieces of the colour export tests: fits of the simulated camera."""

import numpy as np

from camcal.colour.fit.characterise import characterise
from camcal.colour.chart.patches import PatchSet

GAMMA = 2.2  # the simulated camera's encoding: code = linear ** (1 / 2.2)


def codes_of(RGB):
    return np.clip(RGB, 0.0, 1.0) ** (1.0 / GAMMA)


def make_fit(sim, model, linearise="gamma-offset", target_white=None, camera="nikon"):
    """A characterisation of the simulated Nikon from gamma-encoded code values."""
    train = PatchSet(sim.names_train, codes_of(sim.RGB_train), sim.XYZ_train)
    test = PatchSet(sim.names_test, codes_of(sim.RGB_test), sim.XYZ_test)
    return characterise(train, white="D65", model=model, linearise=linearise, test=test,
                        target_white=target_white, camera=camera, loo=False).fit


def code_grid(n=9):
    g = np.linspace(0.0, 1.0, n)
    return np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
