"""The Examples sections of the colour modules run."""

import doctest
import importlib

import pytest

MODULES = ["difference", "fit.evaluate", "fit.terms", "fit.models", "fit.fitting", "spectral.data",
           "spectral.simulate", "spectral.estimate", "chart.linearise", "chart.reference", "chart.detect",
           "fit.record", "fit.select", "chart.patches", "fit.characterise", "spectral.sensitivities",
           "spectral.captures", "fit.illuminant", "export.ocio_versions", "export.ocio_fit"]


@pytest.mark.parametrize("name", MODULES)
def test_doctests(name):
    module = importlib.import_module(f"camcal.colour.{name}")
    result = doctest.testmod(module, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    assert result.failed == 0
