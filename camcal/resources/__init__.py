"""Files camcal ships beside its code: the Blender add-on and the OCIO config templates.

In the source tree they are the top-level folders ``addon/`` and
``ocio_configs/``; ``setup.py`` maps them into the wheel as the packages
``camcal.resources.addon`` and ``camcal.resources.ocio_configs``, so an installed wheel and an editable
install find them with :mod:`importlib.resources`; only a checkout used
without installing it (``PYTHONPATH``) falls back to the folders beside the
package.
"""

from __future__ import annotations

import importlib.resources
from pathlib import Path

from camcal.base.errors import CamcalError

__all__ = ["addon_dir", "ocio_configs_dir"]

#: Where each resource package lives in the source tree (setup.py maps them into the wheel).
_SOURCE_FOLDERS = {"camcal.resources.addon": "addon", "camcal.resources.ocio_configs": "ocio_configs"}


def _folder(package: str) -> Path:
    try:
        folder = importlib.resources.files(package)
    except ModuleNotFoundError:
        # a source checkout used without installing it (PYTHONPATH): the top-level folder
        checkout = Path(__file__).resolve().parents[2] / _SOURCE_FOLDERS[package]
        if (checkout / "__init__.py").is_file():
            return checkout
        raise CamcalError(f"camcal's resource package {package} is not installed (reinstall camcal)") from None
    if not isinstance(folder, Path):  # a zipped install: the folders must be real files for Blender and OCIO
        raise CamcalError(f"{package} is not a folder on disk ({folder}); install camcal unzipped")
    return folder


def addon_dir() -> Path:
    """The Blender add-on's folder (``addon/`` in the source tree)."""
    return _folder("camcal.resources.addon")


def ocio_configs_dir() -> Path:
    """The OCIO config templates' folder (``ocio_configs/`` in the source tree)."""
    return _folder("camcal.resources.ocio_configs")
