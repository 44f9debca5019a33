"""The optional dependencies (pip extras) and the one line a missing one gives.

``pip install camcal`` alone loads, shows, exports and imports rigs,
undistorts images and writes ST-maps (numpy, SciPy, OpenCV, OpenEXR,
PyYAML). The heavier steps need an extra, and import its modules only when
they run, through :func:`require`:

=============  ==========================================  ===============================================
extra          modules                                     what needs it
=============  ==========================================  ===============================================
``calibrate``  ``pycolmap``, ``pyceres``                   board calibration, ``solve``, bundle adjustment
``colour``     ``colour``, ``PyOpenColorIO``, ``rawpy``    colour fits, matches, OCIO / ICC exports, raws
``plots``      ``matplotlib``                              the PNG figures of ``--report``
``dask``       ``distributed``                             ``batch`` and the Dask detection of videos
``usd``        ``pxr``                                     USD cameras (``rig export --to usd``)
``plates``     ``OpenImageIO``                             EXR / DPX / Cineon / TIFF plate sequences
``blender``    ``bpy``                                     the Blender hand-off and the add-on build
=============  ==========================================  ===============================================

``calibrate`` and ``colour`` bring ``plots``; ``all`` is every extra but
``blender`` (bpy pins its own Python and NumPy).
"""

from __future__ import annotations

import importlib
import importlib.util
from types import ModuleType

from camcal.base.errors import CamcalError

__all__ = ["EXTRAS", "MissingExtraError", "check_installed", "missing_extra", "require"]

#: top-level import name -> the pip extra that installs it (pyproject.toml's optional-dependencies).
EXTRAS: dict[str, str] = {
    "pycolmap": "calibrate",
    "pyceres": "calibrate",
    "colour": "colour",
    "PyOpenColorIO": "colour",
    "rawpy": "colour",
    "matplotlib": "plots",
    "distributed": "dask",
    "pxr": "usd",
    "OpenImageIO": "plates",
    "bpy": "blender",
}


class MissingExtraError(CamcalError):
    """An optional module is not installed: one line naming the extra that installs it.

    Parameters
    ----------
    module
        The top-level import name that is missing (``"pycolmap"``).
    extra
        The pip extra that installs it (``"calibrate"``).
    needed_by
        Who needs it, the start of the line (``"camcal solve"``).
    """

    def __init__(self, module: str, extra: str, needed_by: str = "this step of camcal") -> None:
        self.module = module
        self.extra = extra
        super().__init__(self.line(needed_by))

    def line(self, needed_by: str) -> str:
        """``<needed_by> needs the '<extra>' extra (<module> is not installed): pip install 'camcal[<extra>]'``."""
        return (f"{needed_by} needs the '{self.extra}' extra ({self.module} is not installed): "
                f"pip install 'camcal[{self.extra}]'")


def missing_extra(error: BaseException) -> MissingExtraError | None:
    """The :class:`MissingExtraError` behind ``error``, or None when it is not a missing extra.

    A ``ModuleNotFoundError`` counts when the top-level module it names is one
    of :data:`EXTRAS` and is not installed at all (a missing submodule of an
    installed package is a broken install, not a missing extra).
    """
    if isinstance(error, MissingExtraError):
        return error
    if not isinstance(error, ModuleNotFoundError) or not error.name:
        return None
    top = error.name.partition(".")[0]
    if top not in EXTRAS or importlib.util.find_spec(top) is not None:
        return None
    return MissingExtraError(top, EXTRAS[top])


#: modules imported before an optional one: pycolmap's extension carries its own libpng and zlib, and a process
#: that imports it before OpenCV aborts in OpenCV's PNG writer ("double free", pycolmap 4.2.1 / OpenCV 5.0.0)
_IMPORT_BEFORE: dict[str, tuple[str, ...]] = {"pycolmap": ("cv2",)}


def require(module: str) -> ModuleType:
    """Import an optional module, or raise the one line naming the extra that installs it.

    Parameters
    ----------
    module
        An import name whose top-level package is in :data:`EXTRAS`
        (``"pycolmap"``, ``"matplotlib.pyplot"``, ``"pxr.Usd"``).

    Returns
    -------
    types.ModuleType
        The imported module.

    Raises
    ------
    MissingExtraError
        The module's package is not installed.
    ValueError
        ``module`` is not one of :data:`EXTRAS` (a mistake in camcal, not the user's).

    Examples
    --------
    >>> print(MissingExtraError("pycolmap", EXTRAS["pycolmap"], "camcal solve"))
    camcal solve needs the 'calibrate' extra (pycolmap is not installed): pip install 'camcal[calibrate]'
    """
    top = module.partition(".")[0]
    if top not in EXTRAS:
        raise ValueError(f"{top} is not an optional module of camcal, expected one of: {', '.join(sorted(EXTRAS))}")
    try:
        for first in _IMPORT_BEFORE.get(top, ()):
            importlib.import_module(first)
        return importlib.import_module(module)
    except ModuleNotFoundError as error:
        missing = missing_extra(error)
        if missing is None:
            raise
        raise missing from None


def check_installed(module: str) -> None:
    """Raise the one line naming the extra when ``module`` is not installed, without importing it.

    For a module camcal runs in a subprocess but never imports itself
    (``bpy``: the Blender hand-off).

    Raises
    ------
    MissingExtraError
        ``module`` (one of :data:`EXTRAS`) is not installed.
    """
    if importlib.util.find_spec(module) is None:
        raise MissingExtraError(module, EXTRAS[module])
