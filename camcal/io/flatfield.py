"""Flat-field files: grey-card images read as linear RGB, the ``*.json`` record, the gain EXR and Lensfun's
vignetting entry.

- :func:`read_linear_image`: a grey card as linear RGB. Raw files (DNG,
  CR2, NEF...) are linear camera RGB (saturated pixels flagged); float images
  (EXR, 32-bit TIFF) and 16-bit integer images are taken as linear. An 8-bit
  image (PNG, JPEG, 8-bit TIFF) is almost always display-encoded (sRGB or
  Rec. 709 transfer), where dividing by a falloff is wrong: it is refused
  unless ``linear=True`` says it holds linear values.
- :func:`read_neutral_patches`: a CSV ``x,y,R,G,B,patch[,shot]`` of a
  chart's neutral patches seen at several places in the frame.
- :func:`save_flat_field` / :func:`load_flat_field`: the model as JSON
  (:meth:`camcal.colour.flatfield.FlatField.to_dict`), validated on load.
- :func:`write_gain_exr`: the gain ``G`` per pixel as a 32-bit float RGB
  OpenEXR (1 at the optical centre; divide a linear image by it), for tools
  that read images, not camcal's model (a compositor's divide node).
- :func:`write_lensfun_vignetting`: a Lensfun database file with one
  ``<lens>`` holding ``<vignetting model="pa" focal aperture distance k1 k2
  k3/>`` (the channels' common falloff, :func:`~camcal.colour.flatfield.common_radial_terms`)
  and the optical centre as ``<center>``, or that entry added to an existing
  file's one lens (per lens state; fitted about the lens' centre, which
  Lensfun shares between distortion and vignetting): Lensfun's unit there is half the
  shorter side, ``(min(W, H) - 1) / 2`` pixels, its origin the image centre,
  y down (Lensfun 0.3.4 modifier.cpp; checked with lensfunpy in the tests).
  Lensfun's ``pa`` radius is 1 at the half diagonal (mod-color.cpp), as
  camcal's.

References
----------
Lensfun database format: https://lensfun.github.io/manual/latest/elem_calibration.html
(``<vignetting focal aperture distance model k1 k2 k3>``).
"""

from __future__ import annotations

import csv
import io
import math
import os
import xml.etree.ElementTree as ElementTree
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from camcal.base.atomic import atomic_write_text
from camcal.base.errors import CamcalError
from camcal.base.jsonfile import read_json, write_json
from camcal.base.limits import FILE_BYTES, check_file_size
from camcal.colour.flatfield import FlatField, RadialTerms, common_radial_terms
from camcal.io.lensfun import DEFAULT_SENSOR_WIDTH_MM
from camcal.io.lensfun_units import lensfun_aspect, lensfun_number, lensfun_unit_px
from camcal.io.lensfun_vignetting import VignettingState, vignetting_element, vignetting_terms
from camcal.io.points_csv import finite_numbers

__all__ = ["LinearImage", "NeutralPatches", "check_lensfun_file", "load_flat_field", "read_linear_image", "read_neutral_patches",
           "save_flat_field", "write_gain_exr", "write_lensfun_vignetting"]

#: Full frame's diagonal in mm (the crop factor's reference).
_FULL_FRAME_DIAGONAL_MM = math.hypot(36.0, 24.0)
#: Integer-coded pixels at or above this (of full scale) are taken as clipped.
_CLIP = 0.98


@dataclass(frozen=True)
class LinearImage:
    """A grey-card image as linear RGB ``(H, W, 3)`` and the value at which it clips (None: float data)."""

    RGB: NDArray[np.float64]
    clip: float | None


def read_linear_image(path: str | os.PathLike, *, linear: bool = False) -> LinearImage:
    """Read a grey-card image as linear RGB (see the module docstring for what counts as linear).

    Raises
    ------
    CamcalError
        A missing or unreadable file, or an 8-bit image without ``linear``.
    """
    from camcal.io.frames import imread
    from camcal.io.raw import is_raw, read_raw

    path = Path(path)
    if not path.is_file():
        raise CamcalError(f"grey-card image not found: {path}")
    if is_raw(path):
        return LinearImage(read_raw(path).RGB, 1.0)  # saturated pixels are 1.0
    pixels = imread(path)
    if pixels.dtype == np.uint8 and not linear:
        raise CamcalError(f"{path} is an 8-bit image, most likely display-encoded (sRGB): a flat field needs linear "
                          "values; give a raw file, an EXR or a 16-bit TIFF, or say it is linear with --linear")
    if pixels.ndim == 2:
        pixels = np.repeat(pixels[:, :, None], 3, axis=2)
    RGB = pixels[:, :, :3][:, :, ::-1]
    if RGB.dtype.kind in "ui":
        return LinearImage(RGB.astype(np.float64) / float(np.iinfo(RGB.dtype).max), _CLIP)
    return LinearImage(RGB.astype(np.float64), None)


@dataclass(frozen=True)
class NeutralPatches:
    """A neutral-patch CSV's rows: centres ``(N, 2)`` in pixels, linear values ``(N, 3)``, patch and shot names."""

    xy: NDArray[np.float64]
    RGB: NDArray[np.float64]
    patch: tuple[str, ...]
    shot: tuple[str, ...] | None


def read_neutral_patches(path: str | os.PathLike) -> NeutralPatches:
    """Read a CSV ``x,y,R,G,B,patch[,shot]``: each row a neutral patch's centre (pixel (0, 0) the centre of the
    top-left pixel), its linear value, which patch it is and (optional) which photo; ``#`` lines are comments.

    Raises
    ------
    CamcalError
        Naming the file and line of the first problem.
    """
    path = Path(path)
    if not path.is_file():
        raise CamcalError(f"patch file not found: {path}")
    check_file_size(path, FILE_BYTES, "patch file")
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as error:
        raise CamcalError(f"{path}: not UTF-8 text (byte {error.start})") from None
    rows = [(number, [cell.strip() for cell in row]) for number, row in enumerate(csv.reader(io.StringIO(text)), 1)
            if row and any(cell.strip() for cell in row) and not row[0].lstrip().startswith("#")]
    header = rows[0][1] if rows else []
    if header not in (["x", "y", "R", "G", "B", "patch"], ["x", "y", "R", "G", "B", "patch", "shot"]):
        shown = ",".join(header)
        raise CamcalError(f"{path}: the header must be x,y,R,G,B,patch[,shot], got "
                          f"{(shown if shown.isprintable() else repr(shown))[:200] or 'nothing'}")
    numbers, patch, shot = [], [], []
    for number, cells in rows[1:]:
        if len(cells) != len(header):
            raise CamcalError(f"{path}:{number}: expected {len(header)} columns, got {len(cells)}")
        numbers.append(finite_numbers(cells[:5], f"{path}:{number}"))
        patch.append(cells[5])
        shot.append(cells[6] if len(cells) == 7 else "")
    if not numbers:
        raise CamcalError(f"{path}: no patches after the header")
    array = np.array(numbers)
    return NeutralPatches(array[:, :2], array[:, 2:], tuple(patch), tuple(shot) if len(header) == 7 else None)


def save_flat_field(flat: FlatField, path: str | os.PathLike) -> Path:
    """Write the flat field as JSON, atomically; its path."""
    path = Path(path)
    if path.suffix.lower() != ".json":
        raise CamcalError(f"a flat-field file ends in .json, got {path.name!r}")
    return write_json(path, flat.to_dict())


def load_flat_field(path: str | os.PathLike) -> FlatField:
    """Read and validate a flat-field file (:func:`save_flat_field`'s)."""
    data = read_json(path, "flat-field file")
    try:
        return FlatField.from_dict(data)
    except CamcalError as error:
        raise CamcalError(f"{path}: {error}") from None


def write_gain_exr(flat: FlatField, path: str | os.PathLike) -> Path:
    """Write the gain image (32-bit float RGB OpenEXR at the fit's image size), atomically; its path."""
    from camcal.io.frames import imwrite

    path = Path(path)
    if path.suffix.lower() != ".exr":
        raise CamcalError(f"the gain image is an OpenEXR file (.exr), got {path.name!r}")
    return imwrite(path, np.ascontiguousarray(flat.gain()[:, :, ::-1]))


def write_lensfun_vignetting(flat: FlatField, path: str | os.PathLike, *, focal_mm: float, aperture: float,
                             distance_m: float, model: str = "camcal flat field", maker: str = "camcal",
                             mount: str = "Generic", sensor_width_mm: float | None = None) -> RadialTerms:
    """Write the flat field's ``pa`` vignetting entry into a Lensfun database file, atomically.

    A new file holds one ``<lens>`` with the optical centre as its ``<center>``. An existing file holding one
    ``<lens>`` (``rig export --to lensfun``'s, or this function's for another lens state) gets the entry added
    to it, an entry of the same focal length, aperture and distance replaced: Lensfun has one centre per lens
    for distortion and vignetting, so the terms are fitted about the file's ``<center>``.

    Parameters
    ----------
    flat : FlatField
    path : path
        The ``.xml`` file.
    focal_mm, aperture, distance_m : float
        The lens state the flat field was shot at (Lensfun interpolates between entries; a distance of ``inf`` is
        written as Lensfun's 1000 m, :mod:`camcal.io.lensfun_vignetting`).
    model, maker, mount : str
        A new file's ``<lens>`` names.
    sensor_width_mm : float, optional
        A new file's crop factor (full frame's diagonal over the sensor's; default 36 mm wide).

    Returns
    -------
    RadialTerms
        The terms written and the largest deviation from the per-channel flat field they leave.

    Raises
    ------
    CamcalError
        A lens state not > 0, or an existing file that is not a Lensfun file with one ``<lens>`` of the flat
        field's aspect ratio.
    """
    path = Path(path)
    if path.suffix.lower() != ".xml":
        raise CamcalError(f"a Lensfun database file must end in .xml, got {path.name!r}")
    state = VignettingState(focal_mm, aperture, distance_m, flat)
    width, height = flat.image_size
    unit = lensfun_unit_px(flat.image_size)
    image_centre = np.array([(width - 1) / 2.0, (height - 1) / 2.0])
    aspect = lensfun_aspect(flat.image_size)
    if path.exists():
        root, entry, offset = _existing_lens(path, aspect)
        terms = vignetting_terms(flat, offset)
        calibration = entry.find("calibration")
        if calibration is None:
            calibration = ElementTree.SubElement(entry, "calibration")
    else:
        terms = common_radial_terms(flat)
        offset = (terms.centre - image_centre) / unit
        crop = _FULL_FRAME_DIAGONAL_MM / ((sensor_width_mm or DEFAULT_SENSOR_WIDTH_MM) * math.hypot(width, height)
                                          / width)
        root = ElementTree.Element("lensdatabase", version="1")
        entry = ElementTree.SubElement(root, "lens")
        for tag, text in (("maker", maker), ("model", model), ("mount", mount)):
            ElementTree.SubElement(entry, tag).text = text
        ElementTree.SubElement(entry, "center", x=lensfun_number(offset[0]), y=lensfun_number(offset[1]))
        ElementTree.SubElement(entry, "cropfactor").text = lensfun_number(crop)
        ElementTree.SubElement(entry, "aspect-ratio").text = lensfun_number(aspect)
        calibration = ElementTree.SubElement(entry, "calibration")
        root.append(ElementTree.Comment(f" camcal image_size {width} {height} "))
    vignetting_element(calibration, state, terms)
    ElementTree.indent(root)
    atomic_write_text(path, '<?xml version="1.0" encoding="utf-8"?>\n' + ElementTree.tostring(root, "unicode") + "\n")
    return terms


def check_lensfun_file(path: str | os.PathLike) -> None:
    """Refuse, before any fit, a ``.xml`` that exists and is not a Lensfun file with one ``<lens>``."""
    path = Path(path)
    if path.suffix.lower() != ".xml":
        raise CamcalError(f"a Lensfun database file must end in .xml, got {path.name!r}")
    if path.exists():
        _existing_lens(path, None)


def _existing_lens(path: Path, aspect: float | None) -> tuple[ElementTree.Element, ElementTree.Element, NDArray]:
    """An existing Lensfun file's root (comments kept), its one ``<lens>`` and that lens' ``<center>``; its
    aspect ratio checked against ``aspect`` (None: not checked)."""
    check_file_size(path, FILE_BYTES, "Lensfun file")
    try:
        text = path.read_text(encoding="utf-8")
        root = ElementTree.fromstring(text, ElementTree.XMLParser(target=ElementTree.TreeBuilder(insert_comments=True)))
    except (UnicodeDecodeError, ElementTree.ParseError) as error:
        raise CamcalError(f"{path}: not a Lensfun file ({str(error).splitlines()[0]})") from None
    lenses = root.findall("lens") if root.tag == "lensdatabase" else []
    if root.tag != "lensdatabase" or len(lenses) != 1:
        raise CamcalError(f"{path}: camcal adds vignetting to a Lensfun file with one <lens>, this one has "
                          f"{len(lenses)}; give a new file")
    [entry] = lenses

    def number(text: str | None, what: str) -> float:
        numerator, _, denominator = (text or "").partition(":")  # an aspect ratio may be W:H
        try:
            value = float(numerator) / float(denominator or 1.0)
        except (ValueError, ZeroDivisionError):
            value = math.nan
        if not math.isfinite(value):
            raise CamcalError(f"{path}: the lens' {what} must be a number, got {text!r}")
        return value

    center = entry.find("center")
    offset = np.zeros(2) if center is None else np.array([number(center.get(axis, "0"), f"<center {axis}>")
                                                          for axis in ("x", "y")])
    element = entry.find("aspect-ratio")
    if element is not None:
        theirs = number(element.text, "<aspect-ratio>")
        if aspect is not None and abs(theirs / aspect - 1.0) > 0.01:
            raise CamcalError(f"{path}: its lens is for images of aspect ratio {theirs:.4g}, the flat field's are "
                              f"{aspect:.4g}")
    return root, entry, offset
