"""Colour fits in OpenColorIO: input colour spaces, match Looks, the fast image processor.

A characterisation (``*.colour.json``) becomes one input colour space of an
OCIO config, named as the ACES studio configs name camera spaces:
``camcal <camera>`` (the name the Blender add-on looks for), family
``Input/<maker>`` (the raw capture's make, :func:`maker_family`) or
``Input/camcal`` or one given, a short alias ``camcal_<camera>``
(:func:`space_alias`), a Color Interop Forum ID ``camcal:<camera>_scene``
(:func:`space_interop_id`, in configs of OCIO profile 2.5 and later), category
``file-io``, encoding ``log`` for a log curve and ``scene-linear`` otherwise
(:func:`space_encoding`) and a description naming
the chart, the light it was shot under and the one it is for, the model
and its held-out CIEDE2000. Its transform to the config's scene reference
is, in order:

1. the linearisation (code values in [0, 1] to linear camera RGB):
   ``gamma-offset`` curves exactly as ``MatrixTransform`` (offset),
   ``ExponentTransform`` (negative values clamp to 0) and a diagonal
   ``MatrixTransform`` (gain); ``lut1d`` curves as a ``Lut1DTransform`` with
   the fit's own samples; ``named`` curves sampled into a 4096-entry
   ``Lut1DTransform`` (the largest relative error is reported). OCIO clamps
   a ``Lut1DTransform``'s input to [0, 1], the range of code values.
2. the model (linear camera RGB to XYZ under the fit's target white): a
   ``matrix3x3`` fit exactly as a ``MatrixTransform``; any other model as a
   ``FileTransform`` to a CLF file written by OCIO's own writer, holding a
   log2 shaper and a matrix to log-chromaticity coordinates, a tetrahedral
   ``Lut3D`` and an inverse log2 shaper followed by a 3x3 matrix (see
   :func:`camcal.colour.bake.transforms.transform_from_callable`), checked
   within CIEDE2000 0.2 over the chart gamut and plausible surface colours
   (:func:`camcal.colour.bake.samples.bake_model`, the check
   ``--model auto`` uses too).
3. XYZ (target white) to the reference: chromatic adaptation from the
   target white to the ACES white (von Kries with Bradford, as OCIO's ACES
   configs do, or CAT02), the ACES2065-1 ``XYZ -> AP0`` matrix, then the
   base config's ``aces_interchange`` space to its scene reference (an
   identity for the ACES configs and camcal's base; a matrix for Blender's
   config, whose reference is CIE XYZ E).

A camera match (kind ``match``) becomes a Look (:func:`look_from_match`).
:func:`config_spec_from_fits` describes a whole config;
:func:`camcal.io.ocio.export_ocio` writes it. :func:`fit_processor` applies a
fit to images with the same transforms.

A camera's fits for several lights (D65, A, a measured light) go into one
config together, one input space per light named ``camcal <camera>
(<light>)`` (:func:`names_by_illuminant`): the light a fit is for is its
``--for-illuminant`` target, else the illuminant its chart was shot under,
a measured light's file name without its suffix, or a label given for it.
"""

from __future__ import annotations

import posixpath
import re
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import PurePath
from typing import Any

import numpy as np

from camcal.base.errors import CamcalError
from camcal.base.extras import require
from camcal.colour.bake.samples import bake_model, model_chart_samples, model_samples
from camcal.colour.bake.transforms import (
    LUT_SIZES,
    BakedTransform,
    cpu_processor,
    matrix_transform,
    ocio_module,
    transform_from_callable,
)
from camcal.colour.difference import DeltaEStats
from camcal.colour.export.ocio_config import (
    CATS,
    FAMILY,
    LUT_DIR,
    ColourSpaceSpec,
    ConfigSpec,
    LookSpec,
    XYZ_to_reference_matrix,
    colour_space_name,
    linearisation_transforms,
    slug,
)
from camcal.colour.fit.record import ColourFit

__all__ = [
    "maker_family",
    "space_encoding",
    "space_alias",
    "space_interop_id",
    "chart_gamut_samples",
    "bake_samples",
    "bake_fit",
    "SpaceExport",
    "colour_space_from_fit",
    "look_name",
    "look_from_match",
    "config_spec_from_fits",
    "illuminant_label",
    "names_by_illuminant",
    "OUTPUT_SPACES",
    "output_matrix",
    "FitProcessor",
    "fit_processor",
    "fit_transforms",
]


_CORPORATE = {"corporation", "corp", "corp.", "co.", "co", "ltd", "ltd.", "inc", "inc.", "imaging", "company",
              "digital", "gmbh", "ag"}


def maker_family(fit: ColourFit) -> str:
    """``Input/<maker>`` from the fit's raw capture (EXIF Make), else ``Input/camcal``.

    The make is shortened as the ACES studio configs name vendors: corporate
    words dropped, an all-capitals word of more than three letters
    capitalised (``NIKON CORPORATION`` -> ``Nikon``, ``SONY`` -> ``Sony``,
    ``RED`` stays).

    Examples
    --------
    >>> from types import SimpleNamespace
    >>> maker_family(SimpleNamespace(capture={"make": "NIKON CORPORATION"}))
    'Input/Nikon'
    >>> maker_family(SimpleNamespace(capture=None))
    'Input/camcal'
    """
    make = str((getattr(fit, "capture", None) or {}).get("make") or "")
    words = [w for w in make.replace(",", " ").split() if w.lower() not in _CORPORATE]
    words = [w.capitalize() if w.isupper() and len(w) > 3 else w for w in words]
    return f"Input/{' '.join(words)}" if words else FAMILY


def space_encoding(fit: ColourFit) -> str:
    """OCIO encoding of a camera space: ``log`` for a named log curve, else ``scene-linear``.

    A camera's input space is scene-referred whatever its curve: the ACES
    configs' viewing rules offer their ACES views to ``scene-linear`` and
    ``log`` spaces, and video views to the others (``sdr-video``), so a
    camera with a log curve (``ARRI LogC3``, ``S-Log3``, ``ACEScct``...) is
    ``log`` as the studio configs' camera spaces are, and every other one
    (linear raw data, a camera's own tone curve) ``scene-linear``.
    """
    channels = fit.linearisation.channels
    if all(c.kind == "named" and ("log" in c.params["function"].lower() or "cct" in c.params["function"].lower())
           for c in channels):
        return "log"
    return "scene-linear"


def space_alias(name: str) -> str:
    """The short alias of a space name: lower case, ``_`` between words.

    Examples
    --------
    >>> space_alias("camcal A7S-left (D65)")
    'camcal_a7s_left_d65'
    """
    return re.sub(r"[^a-z0-9]+", "_", name.lower()).strip("_")


def space_interop_id(name: str) -> str:
    """The Color Interop Forum ID of a camera space: ``camcal:<alias without camcal_>_scene``.

    A namespaced ID (camcal's spaces are not in the Forum's list), lower
    case, ending ``_scene`` as a scene-referred space's does.

    Examples
    --------
    >>> space_interop_id("camcal A7S-left (D65)")
    'camcal:a7s_left_d65_scene'
    """
    return f"camcal:{space_alias(name).removeprefix('camcal_')}_scene"


def chart_gamut_samples(fit: ColourFit, n: int = 21) -> np.ndarray:
    """Linear camera RGB spanning the chart gamut of a characterisation.

    The chart is the fit's reference chart (the ColorChecker 24 when none is
    recorded or the reference is not a chart, e.g. a spectral training
    set), its XYZ adapted (CAT02) to the fit's target white and
    inverted through the fit (:func:`invert_model`; only converged
    preimages a camera records, see :func:`plausible_surface_samples`); an
    RBF fit adds its centres (its training patches). The samples are those
    patches plus the points of a regular ``n^3`` grid over their bounding
    box that lie in the convex hull of the patches and of the same patches
    two stops darker (divided by 4). Black itself is left out: near it
    CIEDE2000 magnifies absolute errors that no image shows.

    Returns
    -------
    numpy.ndarray
        ``(M, 3)`` linear camera RGB.
    """
    return model_chart_samples(fit.model, fit.target_white_XYZ, fit.reference, n)


def bake_samples(fit: ColourFit) -> np.ndarray:
    """Where a baked fit must hold: :func:`chart_gamut_samples` and :func:`plausible_surface_samples`.

    The surfaces are lit by the fit's training illuminant and adapted to its
    target white, as the fit's own reference XYZ were.
    """
    return model_samples(fit.model, fit.target_white_XYZ, fit.reference, fit.training_illuminant)


def bake_fit(fit: ColourFit, *, max_delta_E: float = 0.2, lut_sizes: Sequence[int] = LUT_SIZES) -> BakedTransform:
    """:func:`bake_model` of a characterisation's model (exact matrix, or the baked Lut3D)."""
    return bake_model(fit.model, fit.target_white_XYZ, reference=fit.reference,
                      illuminant=fit.training_illuminant, max_delta_E=max_delta_E, lut_sizes=lut_sizes)


# --------------------------------------------------------------------------
# Characterisation fits.


@dataclass(frozen=True)
class SpaceExport:
    """What one exported camera colour space is, with its figures.

    ``bake_error``: CIEDE2000 of the baked model over the chart gamut and plausible surface colours
    (``None`` for an exact matrix); ``linearisation_error``: relative error
    of a sampled linearisation (0 when exact); ``clf``: the CLF's path
    relative to the config (``None`` for a matrix fit).
    """

    name: str
    camera: str
    model: str
    kind: str
    lut_size: int | None
    bake_error: DeltaEStats | None
    linearisation_error: float
    clf: str | None

    def summary(self) -> str:
        line = f"{self.name}: {self.model}, "
        if self.kind == "matrix":
            line += "exact MatrixTransform"
        else:
            line += (f"{self.lut_size}^3 Lut3D in {self.clf}, bake error CIEDE2000 mean "
                     f"{self.bake_error.mean:.3f}, max {self.bake_error.max:.3f} over the chart gamut and plausible surfaces")
        if self.linearisation_error:
            line += f"; sampled linearisation, relative error {self.linearisation_error:.1e}"
        return line


def _held_out(evaluation: dict) -> str:
    for key, label in (("test", "independent patches"), ("loo", "leave-one-out"), ("train", "training")):
        stats = evaluation.get(key)
        if stats:
            return (f"held-out CIEDE2000 ({label}, n = {stats['n']}): mean {stats['mean']:.2f}, "
                    f"p95 {stats['p95']:.2f}, max {stats['max']:.2f}")
    return ""  # pragma: no cover - train is always present


def colour_space_from_fit(
    fit: ColourFit,
    camera: str,
    config,
    *,
    cat: str = "Bradford",
    max_delta_E: float = 0.2,
    lut_sizes: Sequence[int] = LUT_SIZES,
    family: str | None = None,
) -> tuple[ColourSpaceSpec, SpaceExport]:
    """The input colour space of a characterisation, for ``config``'s reference.

    Parameters
    ----------
    fit
        The characterisation.
    camera
        Camera name; the space is ``camcal <camera>``.
    config
        The base config (its ``aces_interchange`` role places ACES2065-1).
    cat, max_delta_E, lut_sizes
        See :func:`XYZ_to_reference_matrix` and :func:`transform_from_callable`.
    family
        The space's family (a studio's own, e.g. ``Input/Witness cameras``);
        default :func:`maker_family`.

    Returns
    -------
    ColourSpaceSpec, SpaceExport
    """
    ocio = ocio_module()
    name = colour_space_name(camera)
    lin, lin_error = linearisation_transforms(fit.linearisation)
    to_ref = XYZ_to_reference_matrix(config, fit.target_white_XYZ, cat)
    model = fit.model
    files: dict = {}
    clf = None
    baked = bake_fit(fit, max_delta_E=max_delta_E, lut_sizes=lut_sizes)
    if baked.kind == "matrix":
        steps = [*lin, matrix_transform(to_ref @ baked.matrix)]
        how = "exact matrix"
    else:
        clf = f"{LUT_DIR}/camcal_{slug(camera)}.clf"
        how = (f"baked as a log-chromaticity shaper and {baked.lut_size}^3 Lut3D ({clf}), bake error CIEDE2000 mean "
               f"{baked.bake_error.mean:.3f}, max {baked.bake_error.max:.3f} over the chart gamut and plausible surfaces")
        files[clf] = baked.clf_text(f"camcal:{slug(camera)}",
                                    f"camcal {model.label}: linear camera RGB of {camera} to CIE XYZ "
                                    f"({fit.target_white}, white Y = 1)")
        steps = [*lin, ocio.FileTransform(posixpath.basename(clf), interpolation=ocio.INTERP_TETRAHEDRAL),
                 matrix_transform(to_ref)]
    capture = fit.capture or {}
    body = " ".join(str(capture[key]) for key in ("make", "model") if capture.get(key))
    chart = f"the {fit.reference} chart" if fit.reference else "a chart"
    light = f"shot under {fit.training_illuminant}"
    if fit.illuminant_change:
        light += f", for {fit.illuminant_change['for_illuminant']}"
    description = (f"Convert camera {camera}{f' ({body})' if body else ''} to the scene reference: camcal "
                   f"characterisation from {chart} {light}; {model.label}, linearisation "
                   f"{fit.linearisation.label}; {_held_out(fit.evaluation)}; XYZ ({fit.target_white}) "
                   f"to the reference with {cat}; model {how}.")
    spec = ColourSpaceSpec(name, family or maker_family(fit), description, tuple(steps), files=files,
                           encoding=space_encoding(fit), aliases=(space_alias(name),), interop_id=space_interop_id(name))
    report = SpaceExport(name, camera, model.label, baked.kind, baked.lut_size, baked.bake_error, lin_error, clf)
    return spec, report


def look_name(source: str, target: str) -> str:
    """The Look of a camera match: ``camcal match <source> to <target>``."""
    return f"camcal match {source} to {target}"


def look_from_match(match, config, *, max_delta_E: float = 0.2,
                    lut_sizes: Sequence[int] = LUT_SIZES) -> tuple[LookSpec, SpaceExport]:
    """A camera match (kind ``match``) as an OCIO Look on linear camera values.

    The Look's process space is the config's ``data`` role (no conversion):
    applied to camera B's *linear* RGB it gives camera A's linear RGB
    (``match.apply``). A matrix match is an exact ``MatrixTransform``; the
    others are baked like a characterisation (:func:`transform_from_callable`)
    over a cube of linear RGB from 1/64 to 1, the error measured with the
    outputs read as linear Rec. 709 / D65 (camera A's RGB has no XYZ here).
    """
    colour = require("colour")

    ocio = ocio_module()
    process_space = config.getRoleColorSpace(ocio.ROLE_DATA) if config.hasRole(ocio.ROLE_DATA) else None
    if not process_space:
        raise CamcalError("the base config has no 'data' role: a match Look needs a space without conversion")
    source, target = match.source or "B", match.target or "A"
    name = look_name(source, target)
    files: dict = {}
    clf = None
    if match.matrix is not None:
        baked = transform_from_callable(match.apply, matrix=match.matrix)
        transform = matrix_transform(baked.matrix)
    else:
        levels = np.geomspace(1.0 / 64.0, 1.0, 9)
        cube = np.stack(np.meshgrid(levels, levels, levels, indexing="ij"), axis=-1).reshape(-1, 3)
        rec709 = colour.RGB_COLOURSPACES["ITU-R BT.709"]
        baked = transform_from_callable(
            match.apply, samples=cube, white_XYZ=colour.xy_to_XYZ(rec709.whitepoint),
            to_XYZ=lambda RGB: RGB @ rec709.matrix_RGB_to_XYZ.T, max_delta_E=max_delta_E, lut_sizes=lut_sizes,
        )
        clf = f"{LUT_DIR}/camcal_match_{slug(source)}_to_{slug(target)}.clf"
        files[clf] = baked.clf_text(f"camcal:match:{slug(source)}:{slug(target)}",
                                    f"camcal {match.model.label}: linear {source} RGB to linear {target} RGB")
        transform = ocio.FileTransform(posixpath.basename(clf), interpolation=ocio.INTERP_TETRAHEDRAL)
    description = (f"camcal colour match of camera {source} to camera {target} ({match.model.label}) on linear "
                   f"camera values; {_held_out(match.evaluation)}")
    look = LookSpec(name, process_space, transform, description=description, files=files)
    report = SpaceExport(name, source, match.model.label, baked.kind, baked.lut_size, baked.bake_error, 0.0, clf)
    return look, report


def config_spec_from_fits(
    fits: Sequence[tuple[str, ColourFit]],
    base: Any,
    *,
    cat: str = "Bradford",
    max_delta_E: float = 0.2,
    lut_sizes: Sequence[int] = LUT_SIZES,
    matches: Sequence = (),
    family: str | None = None,
) -> tuple[ConfigSpec, tuple[SpaceExport, ...]]:
    """Describe a config: ``base`` plus one input colour space per camera and one Look per match.

    Parameters
    ----------
    fits
        ``(camera name, fit)`` pairs; names must be unique.
    base
        The base ``PyOpenColorIO.Config`` (:func:`camcal.io.ocio.load_base_config`).
    cat, max_delta_E, lut_sizes, family
        See :func:`colour_space_from_fit`.
    matches
        Camera matches (kind ``match``), each a Look (:func:`look_from_match`).

    Returns
    -------
    ConfigSpec, reports
        The spec (with its CLF files' text) and what each space and Look is,
        the colour spaces first.
    """
    names = [camera for camera, _ in fits]
    if len(set(names)) != len(names):
        raise CamcalError(f"camera names must be unique, got {', '.join(names)}")
    specs, reports = [], []
    for camera, fit in fits:
        spec, report = colour_space_from_fit(fit, camera, base, cat=cat, max_delta_E=max_delta_E,
                                             lut_sizes=lut_sizes, family=family)
        specs.append(spec)
        reports.append(report)
    looks = []
    for match in matches:
        look, report = look_from_match(match, base, max_delta_E=max_delta_E, lut_sizes=lut_sizes)
        looks.append(look)
        reports.append(report)
    return ConfigSpec(base=base, colour_spaces=tuple(specs), looks=tuple(looks)), tuple(reports)


_LIGHT_FILE_SUFFIXES = (".csv", ".spd", ".txt", ".json")


def illuminant_label(fit: ColourFit) -> str:
    """The light a fit is for: its illuminant change's target, else its training illuminant.

    A measured light given as a file becomes the file's name without its
    suffix.

    Examples
    --------
    >>> from types import SimpleNamespace
    >>> illuminant_label(SimpleNamespace(illuminant_change=None, training_illuminant="/lights/studio LED.csv"))
    'studio LED'
    >>> illuminant_label(SimpleNamespace(illuminant_change={"for_illuminant": "A"}, training_illuminant="D65"))
    'A'
    """
    change = getattr(fit, "illuminant_change", None)
    label = str(change["for_illuminant"]) if change else str(fit.training_illuminant)
    pure = PurePath(label)
    if pure.suffix.lower() in _LIGHT_FILE_SUFFIXES:
        label = pure.stem
    return label.strip()


def names_by_illuminant(fits: Sequence[tuple[str, ColourFit, str | None]]) -> list[tuple[str, ColourFit]]:
    """``(camera, fit, light or None)`` to ``(camera (light), fit)``: one space name per camera and light.

    The light is :func:`illuminant_label` unless given; a camera name that
    already ends with `` (light)`` (a ``colour fit --for-illuminant`` fit's)
    keeps it once.

    Raises
    ------
    CamcalError
        Two fits for the same camera and light.

    Examples
    --------
    >>> from types import SimpleNamespace
    >>> d65 = SimpleNamespace(illuminant_change=None, training_illuminant="D65")
    >>> a = SimpleNamespace(illuminant_change={"for_illuminant": "A"}, training_illuminant="D65")
    >>> [n for n, _ in names_by_illuminant([("nikon", d65, None), ("nikon (A)", a, None), ("nikon", d65, "LED")])]
    ['nikon (D65)', 'nikon (A)', 'nikon (LED)']
    """
    named: list[tuple[str, ColourFit]] = []
    for camera, fit, light in fits:
        light = (light or illuminant_label(fit)).strip()
        if not light:
            raise CamcalError(f"the fit of camera {camera!r} names no light: give it as LIGHT=FIT.colour.json")
        base = camera.removesuffix(f" ({light})")
        named.append((f"{base} ({light})", fit))
    names = [name for name, _ in named]
    twice = sorted({name for name in names if names.count(name) > 1})
    if twice:
        raise CamcalError(f"two fits for the same camera and light: {', '.join(twice)} (name the lights with "
                          f"LIGHT=FIT.colour.json)")
    return named


# --------------------------------------------------------------------------
# Applying a fit to images: one OCIO CPU processor.

#: Output spaces of :func:`fit_processor`: name -> colour-science RGB colour space (``None``: the fit's XYZ).
OUTPUT_SPACES = {"CIE XYZ": None, "ACES2065-1": "ACES2065-1", "ACEScg": "ACEScg", "lin Rec.709": "ITU-R BT.709"}


def output_matrix(white_XYZ: Any, space: str, cat: str = "Bradford") -> np.ndarray:
    """Matrix from XYZ under ``white_XYZ`` (Y = 1) to a linear output space of :data:`OUTPUT_SPACES`.

    ``"CIE XYZ"`` is the identity (the fit's own XYZ, relative to its target
    white); the RGB spaces are ``M_XYZ->RGB @ CAT(white -> space white)``
    (von Kries with ``cat``; colour-science's matrices: ACES2065-1 AP0,
    ACEScg AP1, both with the ACES white; linear Rec. 709 with D65).

    Examples
    --------
    >>> output_matrix([0.95047, 1.0, 1.08883], "CIE XYZ").tolist()[0]
    [1.0, 0.0, 0.0]
    """
    colour = require("colour")

    if space not in OUTPUT_SPACES:
        raise CamcalError(f"unknown output space {space!r}, expected one of: {', '.join(OUTPUT_SPACES)}")
    if cat not in CATS:
        raise CamcalError(f"unknown adaptation {cat!r}, expected one of: {', '.join(CATS)}")
    if OUTPUT_SPACES[space] is None:
        return np.eye(3)
    rgb = colour.RGB_COLOURSPACES[OUTPUT_SPACES[space]]
    adapt = colour.adaptation.matrix_chromatic_adaptation_VonKries(
        np.asarray(white_XYZ, dtype=np.float64), colour.xy_to_XYZ(rgb.whitepoint), transform=cat)
    return rgb.matrix_XYZ_to_RGB @ adapt


@dataclass(frozen=True, eq=False)
class FitProcessor:
    """A characterisation applied to images by one OCIO CPU processor.

    The processor is the exported colour space's own transform: the
    linearisation (exact, or sampled for ``named`` curves), the model (an
    exact ``MatrixTransform`` for ``matrix3x3``; otherwise the baked
    log-chromaticity Lut3D of :func:`bake_fit`, within ``bake_error`` of the
    fit), then the matrix to ``space`` (:func:`output_matrix`).

    Attributes
    ----------
    space
        Output space (a key of :data:`OUTPUT_SPACES`).
    kind
        ``"matrix"`` (exact) or ``"lut3d"`` (baked).
    bake_error
        CIEDE2000 of the bake over the chart gamut and plausible surfaces
        (``None`` when exact).
    cpu
        The ``PyOpenColorIO.CPUProcessor``.
    """

    space: str
    kind: str
    bake_error: DeltaEStats | None
    cpu: Any

    def apply(self, codes: Any, *, in_place: bool = False) -> np.ndarray:
        """Code values ``(..., 3)`` in [0, 1] to ``space``, float32, same shape.

        ``in_place``: a C-contiguous float32 array is processed in place (no copy).
        """
        if in_place and isinstance(codes, np.ndarray) and codes.dtype == np.float32 and codes.flags.c_contiguous:
            pixels = codes
        else:
            pixels = np.array(codes, dtype=np.float32, order="C", copy=True)
        if pixels.shape[-1] != 3:
            raise CamcalError(f"expected pixels with 3 channels (..., 3), got shape {pixels.shape}")
        self.cpu.applyRGB(pixels)
        return pixels


def fit_processor(fit: ColourFit, space: str = "CIE XYZ", *, cat: str = "Bradford", max_delta_E: float = 0.2,
                  lut_sizes: Sequence[int] = LUT_SIZES) -> FitProcessor:
    """The OCIO CPU processor of a characterisation, from code values to ``space``.

    Parameters
    ----------
    fit
        The characterisation.
    space
        ``"CIE XYZ"`` (the fit's XYZ, target white Y = 1), ``"ACES2065-1"``,
        ``"ACEScg"`` or ``"lin Rec.709"``.
    cat, max_delta_E, lut_sizes
        See :func:`output_matrix` and :func:`bake_fit` (a fit the exporter
        refuses is refused here too).

    Returns
    -------
    FitProcessor
    """
    ocio = ocio_module()
    steps, baked, _ = fit_transforms(fit, space, cat=cat, max_delta_E=max_delta_E, lut_sizes=lut_sizes)
    cpu = cpu_processor(ocio.GroupTransform(steps))
    return FitProcessor(space, baked.kind, baked.bake_error, cpu)


def fit_transforms(fit: ColourFit, space: str = "CIE XYZ", *, cat: str = "Bradford", max_delta_E: float = 0.2,
                   lut_sizes: Sequence[int] = LUT_SIZES) -> tuple[list, BakedTransform, float]:
    """The OCIO transforms of a characterisation from code values to ``space``, inline (no file).

    The linearisation (:func:`linearisation_transforms`), the model (an exact
    matrix, merged with the output matrix, or the baked Lut3D of
    :func:`bake_fit`), then :func:`output_matrix`.

    Returns
    -------
    transforms, baked, linearisation_error
        The list of OCIO transforms, the baked model and the largest relative
        error of a sampled linearisation (0 when exact).
    """
    out = output_matrix(fit.target_white_XYZ, space, cat)
    lin, lin_error = linearisation_transforms(fit.linearisation)
    baked = bake_fit(fit, max_delta_E=max_delta_E, lut_sizes=lut_sizes)
    if baked.kind == "matrix":
        return [*lin, matrix_transform(out @ baked.matrix)], baked, lin_error
    return [*lin, *list(baked.transform), matrix_transform(out)], baked, lin_error
