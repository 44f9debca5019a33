"""The Examples sections of the colour modules run."""

import doctest
import importlib

import pytest

MODULES = ["evaluate", "models", "spectral", "linearise", "chart", "fitfile", "select", "patches", "characterise",
           "ssf", "illuminant"]


@pytest.mark.parametrize("name", MODULES)
def test_doctests(name):
    module = importlib.import_module(f"camcal.colour.{name}")
    result = doctest.testmod(module, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    assert result.failed == 0
