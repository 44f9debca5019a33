"""camcal: geometric and colour camera calibration for VFX pipelines.

The public Python API is one function per verb of the ``camcal`` command,
with the command's defaults, quality gate, progress and errors (the command
parses its options, calls the function and prints its result):

======================  ==================================================  ======================
function                what it does                                        result
======================  ==================================================  ======================
:func:`calibrate_board` one camera or a rig from chessboard / ChArUco       :class:`BoardCalibration`
                        images or videos (``camcal calibrate board``)
:func:`solve`           cameras from image folders: structure from motion   :class:`Solve`
                        and bundle adjustment (``camcal solve``)
:func:`rectify`         2 or N views onto one image plane, their images     :class:`Rectification`
                        and report (``camcal rectify``)
:func:`undistort`       undistorted images of a rig camera and its pinhole  :class:`Undistortion`
                        rig (``camcal undistort``)
:func:`load_rig`        read and validate a ``*.rig.json``                  :class:`Rig`
:func:`export_rig`      a rig for OpenCV, Kalibr, COLMAP, USD, Nuke, 3DE    ``ExportResult``
                        (``camcal rig export``)
:func:`import_rig`      another tool's camera file as a rig                 :class:`RigImport`
                        (``camcal rig import``)
:func:`fit_colour`      camera RGB to CIE XYZ from a chart photo or         :class:`ColourFit`
                        patches (``camcal colour fit``)
:func:`export_colour`   colour fits as OCIO colour spaces (config + CLF)    :class:`ColourExport`
                        and ICC camera profiles (``camcal colour export``)
:func:`fit_flat_field`  a lens's flat field and vignetting from grey cards   :class:`FlatFieldFit`
                        (``camcal colour flatfield``)
======================  ==================================================  ======================

for a zoom or a refocused lens :func:`calibrate_profile` (a lens profile over
focal length and focus distance, ``camcal calibrate profile``, giving a
:class:`ProfileCalibration`) and :func:`lens_rig` (a camera at a lens state
of a profile, or per frame from lens metadata, ``camcal lens``, giving a
:class:`LensRig`); and the data model: :class:`Rig`, :class:`Camera`, and :class:`CamcalError`,
the one exception a user's mistake raises (its message is the line the
command prints). Every name in :data:`__all__` is public; the modules behind
them are not (their names may change between versions).

``import camcal`` is light: each name is imported when first used (PEP 562),
so OpenCV, pycolmap, Dask, USD and the colour libraries load only when a
function that needs them runs.

Examples
--------
>>> import camcal
>>> result = camcal.calibrate_board({"left": "shots/left*.jpg", "right": "shots/right*.jpg"},
...                                 "chessboard:9x6:0.03", out="stereo.rig.json")  # doctest: +SKIP
>>> result.rms_px, result.rig.cameras[1].c  # doctest: +SKIP
"""

from __future__ import annotations

import importlib
from typing import TYPE_CHECKING, Any

__version__ = "0.1.0"

#: Public name -> the module that defines it, imported on first use.
_EXPORTS: dict[str, str] = {
    "calibrate_board": "camcal.api.board",
    "BoardCalibration": "camcal.api.board",
    "calibrate_profile": "camcal.api.profile",
    "ProfileCalibration": "camcal.api.profile",
    "lens_rig": "camcal.api.lens",
    "LensRig": "camcal.api.lens",
    "solve": "camcal.api.reconstruction",
    "Solve": "camcal.api.reconstruction",
    "rectify": "camcal.api.rectification",
    "Rectification": "camcal.api.rectification",
    "undistort": "camcal.api.undistortion",
    "Undistortion": "camcal.api.undistortion",
    "load_rig": "camcal.api.rig",
    "export_rig": "camcal.api.rig",
    "import_rig": "camcal.api.rig",
    "RigImport": "camcal.api.rig",
    "fit_colour": "camcal.api.colour",
    "ColourFit": "camcal.api.colour",
    "export_colour": "camcal.api.colour",
    "ColourExport": "camcal.api.colour",
    "fit_flat_field": "camcal.api.flatfield",
    "FlatFieldFit": "camcal.api.flatfield",
    "Rig": "camcal.model.rig",
    "Camera": "camcal.model.rig",
    "CamcalError": "camcal.base.errors",
}

__all__ = ["__version__", *_EXPORTS]

if TYPE_CHECKING:  # for type checkers and editors; at run time the names load on first use
    from camcal.api.board import BoardCalibration, calibrate_board
    from camcal.api.lens import LensRig, lens_rig
    from camcal.api.profile import ProfileCalibration, calibrate_profile
    from camcal.api.colour import ColourExport, ColourFit, export_colour, fit_colour
    from camcal.api.flatfield import FlatFieldFit, fit_flat_field
    from camcal.api.reconstruction import Solve, solve
    from camcal.api.rectification import Rectification, rectify
    from camcal.api.rig import RigImport, export_rig, import_rig, load_rig
    from camcal.api.undistortion import Undistortion, undistort
    from camcal.base.errors import CamcalError
    from camcal.model.rig import Camera, Rig


def __getattr__(name: str) -> Any:
    """A public name, imported from its module the first time it is used (PEP 562)."""
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'camcal' has no attribute {name!r}")
    value = getattr(importlib.import_module(module), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    """The public names (:data:`__all__`) and the module's own dunders."""
    return sorted(set(__all__) | {name for name in globals() if name.startswith("__")})
