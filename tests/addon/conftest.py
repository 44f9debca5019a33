"""Fixtures for the Blender add-on's tests.

The add-on is loaded as package ``camcal_rig`` (as Blender loads it, with
relative imports). Tests marked by using the ``bpy`` fixture need the bpy
module (the ``blender`` extra) and start from Blender's empty factory state.
Reference projections use plain numpy with camcal's convention:
``x ~ K [R | -R c] X``, pixel centres at integers.
"""

from __future__ import annotations

import importlib

import pytest

from camcal.blender_bridge import load_addon


@pytest.fixture(scope="session")
def addon():
    """The add-on package with its pure modules imported (usable without bpy)."""
    package = load_addon()
    for name in ("rigfile", "mapping", "plyfile", "pngfile"):
        importlib.import_module(f"{package.__name__}.{name}")
    return package


@pytest.fixture
def bpy():
    """The bpy module, reset to an empty factory scene for each test."""
    bpy = pytest.importorskip("bpy")
    bpy.ops.wm.read_factory_settings(use_empty=True)
    yield bpy
    bpy.ops.wm.read_factory_settings(use_empty=True)
