"""OpenColorIO configs: describe (specs), then build and validate; a fit's linearisation and white as transforms.

:class:`ColourSpaceSpec`, :class:`LookSpec`, :class:`ConfigSpec` describe a
config; :func:`build_ocio_config` builds and validates it (writing it with its
CLF files: :func:`camcal.io.ocio.write_ocio_config`); :func:`add_look` adds a
Look to a config. :func:`linearisation_transforms` and
:func:`XYZ_to_reference_matrix` are the first and last steps of a camera
colour space (:mod:`camcal.colour.export.ocio_fit`).

References
----------
- Academy of Motion Picture Arts and Sciences (2014). TB-2014-004:
  Informative Notes on SMPTE ST 2065-1 - ACES (AP0 primaries, white).
- Lam, K. M. (1985). Metamerism and colour constancy (Bradford CAT).
"""

from __future__ import annotations

import copy
import os
import re
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from camcal.base.errors import CamcalError
from camcal.base.extras import require
from camcal.colour.bake.transforms import apply_cpu, cpu_processor, matrix_transform, ocio_module
from camcal.colour.chart.linearise import Linearisation
from camcal.colour.export.ocio_versions import at_profile_version

__all__ = [
    "STUDIO_CONFIG",
    "CAMCAL_BASE",
    "FAMILY",
    "CATS",
    "CURVE_SAMPLES",
    "INTEROP_ID_VERSION",
    "LUT_DIR",
    "colour_space_name",
    "slug",
    "linearisation_transforms",
    "XYZ_to_reference_matrix",
    "ColourSpaceSpec",
    "LookSpec",
    "ConfigSpec",
    "add_look",
    "build_ocio_config",
]

STUDIO_CONFIG = "ocio://studio-config-latest"
CAMCAL_BASE = "camcal"
FAMILY = "Input/camcal"
CATS = ("Bradford", "CAT02")
CURVE_SAMPLES = 4096
#: The first OCIO profile version whose colour spaces have an ``interop_id``.
INTEROP_ID_VERSION = (2, 5)
LUT_DIR = "luts"


def colour_space_name(camera: str) -> str:
    """The colour space name of a camera: ``camcal <camera>`` (what the Blender add-on expects).

    Examples
    --------
    >>> colour_space_name("A7S-left")
    'camcal A7S-left'
    """
    return f"camcal {camera}"


def slug(text: str) -> str:
    """``text`` as a file-name part."""
    return re.sub(r"[^A-Za-z0-9._-]+", "_", text).strip("_") or "camera"


# Pieces of a camera colour space.


def linearisation_transforms(linearisation: Linearisation) -> tuple[list, float]:
    """OCIO transforms of a fit's linearisation, and their largest error.

    Parameters
    ----------
    linearisation
        The fit's per-channel curves.

    Returns
    -------
    transforms, error
        A list of OCIO transforms (empty for the identity) and the largest
        relative error ``|L_ocio - L| / max(L(1), 1e-6)`` over code values in
        [0, 1] (0 for exact forms: identity, gamma-offset, lut1d).

    Notes
    -----
    ``gamma-offset`` ``L = k max(V - o, 0)^g`` is exact:
    ``MatrixTransform(offset -o) -> ExponentTransform(g, negatives clamp)
    -> MatrixTransform(diag k)``. ``lut1d`` curves of equal length are a
    ``Lut1DTransform`` with their samples (linear interpolation, as in
    camcal). Other curves (``named``, mixtures) are sampled at 4096 code
    values.
    """
    ocio = ocio_module()
    channels = linearisation.channels
    kinds = {c.kind for c in channels}
    if kinds == {"none"}:
        return [], 0.0
    if kinds == {"gamma-offset"}:
        p = [c.params for c in channels]
        return [
            matrix_transform(np.eye(3), [-q["offset"] for q in p]),
            ocio.ExponentTransform([q["gamma"] for q in p] + [1.0], negativeStyle=ocio.NEGATIVE_CLAMP),
            matrix_transform(np.diag([q["gain"] for q in p])),
        ], 0.0
    lengths = {len(c.params.get("samples", ())) for c in channels}
    exact = kinds == {"lut1d"} and len(lengths) == 1
    n = lengths.pop() if exact else CURVE_SAMPLES
    codes = np.linspace(0.0, 1.0, n)
    table = np.stack([np.asarray(c.params["samples"]) if exact else c.apply(codes) for c in channels], axis=-1)
    lut = ocio.Lut1DTransform(n, False)
    lut.setInterpolation(ocio.INTERP_LINEAR)
    lut.setData(np.ascontiguousarray(table, dtype=np.float32).ravel())
    if exact:
        return [lut], 0.0
    probe = np.linspace(0.0, 1.0, 4 * n + 1)
    truth = linearisation.apply(np.repeat(probe[:, None], 3, axis=1))
    got = apply_cpu(cpu_processor(lut), np.repeat(probe[:, None], 3, axis=1))
    scale = np.maximum(np.abs(truth[-1]), 1e-6)
    return [lut], float(np.max(np.abs(got - truth) / scale))


def _aces_to_reference(config) -> np.ndarray:
    """Matrix from ACES2065-1 (the ``aces_interchange`` role) to the config's scene reference."""
    ocio = ocio_module()
    name = config.getRoleColorSpace("aces_interchange") if config.hasRole("aces_interchange") else None
    space = config.getColorSpace(name) if name else None
    if space is None:
        raise CamcalError("the base config has no aces_interchange role: cannot place camera XYZ in its reference")
    to_ref = space.getTransform(ocio.COLORSPACE_DIR_TO_REFERENCE)
    if to_ref is not None:
        processor = config.getProcessor(to_ref)
    else:
        from_ref = space.getTransform(ocio.COLORSPACE_DIR_FROM_REFERENCE)
        if from_ref is None:
            return np.eye(3)
        processor = config.getProcessor(from_ref, ocio.TRANSFORM_DIR_INVERSE)
    cpu = processor.getDefaultCPUProcessor()
    A = apply_cpu(cpu, np.vstack([np.eye(3), np.zeros((1, 3))]))
    M = (A[:3] - A[3]).T
    probe = np.random.default_rng(0).uniform(0.0, 2.0, (16, 3))
    if np.abs(A[3]).max() > 1e-6 or np.abs(apply_cpu(cpu, probe) - probe @ M.T).max() > 1e-4:
        raise CamcalError(f"the base config's {name!r} -> reference transform is not a matrix")
    return M


def XYZ_to_reference_matrix(config, white_XYZ: Any, cat: str = "Bradford") -> np.ndarray:
    """Matrix from XYZ under ``white_XYZ`` (Y = 1) to the config's scene reference.

    Parameters
    ----------
    config
        The ``PyOpenColorIO.Config`` (needs the ``aces_interchange`` role).
    white_XYZ
        White of the XYZ (the fit's target white).
    cat
        ``"Bradford"`` (OCIO's ACES configs) or ``"CAT02"``.

    Returns
    -------
    numpy.ndarray
        ``(3, 3)``: ``M_ref = A_ref @ M_AP0 @ CAT(white -> ACES white)`` with
        ``M_AP0`` the ACES2065-1 ``XYZ -> RGB`` matrix (colour-science).
    """
    colour = require("colour")

    if cat not in CATS:
        raise CamcalError(f"unknown adaptation {cat!r}, expected one of: {', '.join(CATS)}")
    aces = colour.RGB_COLOURSPACES["ACES2065-1"]
    aces_white = colour.xy_to_XYZ(aces.whitepoint)
    adapt = colour.adaptation.matrix_chromatic_adaptation_VonKries(
        np.asarray(white_XYZ, dtype=np.float64), aces_white, transform=cat)
    return _aces_to_reference(config) @ aces.matrix_XYZ_to_RGB @ adapt


# --------------------------------------------------------------------------
# Describe, then build.


@dataclass(frozen=True, eq=False)
class ColourSpaceSpec:
    """A colour space to add: its transform to the scene reference and its files.

    Attributes
    ----------
    name, family, description, encoding
        As OCIO takes them (``encoding``: ``scene-linear``, ``log``...).
    to_reference
        OCIO transforms applied in order, from this space to the reference.
    files
        ``{relative path: text}`` written beside the config (CLF files under
        ``luts/``, which the config's search path holds).
    categories
        OCIO categories (``file-io`` lists it for reading images).
    aliases
        Other names OCIO finds the space by (short, as the ACES configs'
        ``arri_logc3_ei800``).
    interop_id
        The Color Interop Forum ID (``namespace:name_scene``, as the ACES
        studio configs' ``ocio:arrilogc4_awg4_scene``): written, and added to
        the aliases (OCIO requires a namespaced ID to name a space), in
        configs of profile version 2.5 and later, which have the field.
    """

    name: str
    family: str
    description: str
    to_reference: tuple
    encoding: str = "scene-linear"
    files: dict = field(default_factory=dict)
    categories: tuple[str, ...] = ("file-io",)
    aliases: tuple[str, ...] = ()
    interop_id: str | None = None


@dataclass(frozen=True, eq=False)
class LookSpec:
    """A Look: a transform applied in ``process_space`` (e.g. a camera match).

    ``transform`` is an OCIO transform (a ``FileTransform`` to a CLF listed in
    ``files``, or an inline ``MatrixTransform``/``GroupTransform``).
    """

    name: str
    process_space: str
    transform: Any
    description: str = ""
    files: dict = field(default_factory=dict)


@dataclass(frozen=True, eq=False)
class ConfigSpec:
    """A config: a base plus colour spaces and looks.

    ``base``: the base ``PyOpenColorIO.Config`` (left unchanged: the build
    works on a copy); :func:`camcal.io.ocio.load_base_config` loads
    ``"camcal"`` (``ocio_configs/camcal_base.ocio``), an ``ocio://`` built-in
    (:data:`STUDIO_CONFIG`, the ACES studio config) or a ``.ocio`` file.
    ``profile_version``: ``(major, minor)`` the config is written at, at
    most (:func:`camcal.colour.export.ocio_versions.at_profile_version`);
    ``None`` keeps the base's. ``home``: the folder the config is written
    to; a base that lives there (a studio's config extended in place) keeps
    its search paths as they are, any other base's relative ones are made
    absolute.
    """

    base: Any
    colour_spaces: tuple[ColourSpaceSpec, ...] = ()
    looks: tuple[LookSpec, ...] = ()
    name: str | None = None
    profile_version: tuple[int, int] | None = None
    home: str | None = None

    @property
    def files(self) -> dict:
        out: dict = {}
        for item in (*self.colour_spaces, *self.looks):
            out.update(item.files)
        return out


def add_look(config, look: LookSpec) -> None:
    """Add a Look to an editable ``PyOpenColorIO.Config``.

    Parameters
    ----------
    config
        The config (``createEditableCopy()`` of a loaded one).
    look
        Name, process space (must exist in the config), transform.

    Raises
    ------
    CamcalError
        The process space is missing or the name is taken.
    """
    ocio = ocio_module()
    if config.getColorSpace(look.process_space) is None:
        raise CamcalError(f"look {look.name!r}: process space {look.process_space!r} is not in the config")
    if config.getLook(look.name) is not None:
        raise CamcalError(f"look {look.name!r} already exists in the base config")
    config.addLook(ocio.Look(name=look.name, processSpace=look.process_space, transform=look.transform,
                             description=look.description))


def build_ocio_config(spec: ConfigSpec):
    """Build and validate the config a :class:`ConfigSpec` describes.

    The base is copied (at ``spec.profile_version`` when it is newer), its
    search paths are made absolute unless it is extended in place (a file
    base's own LUTs stay reachable from the new config's folder) and
    ``luts`` is appended, the colour spaces and looks are added and
    ``config.validate()`` runs; its errors propagate (as
    :class:`CamcalError`).

    Returns
    -------
    PyOpenColorIO.Config
    """
    ocio = ocio_module()
    config = copy.deepcopy(spec.base) if spec.profile_version is None else at_profile_version(
        spec.base, spec.profile_version)
    if spec.name:
        config.setName(spec.name)
    # the base's own LUT folders, made absolute when the new config lives elsewhere, then luts/
    working = config.getWorkingDir()
    if not (working and spec.home and os.path.realpath(working) == os.path.realpath(spec.home)):
        paths = [p if os.path.isabs(p) or not working else os.path.join(working, p) for p in config.getSearchPaths()]
        config.clearSearchPaths()
        for path in paths:
            config.addSearchPath(path)
    if spec.files and LUT_DIR not in config.getSearchPaths():
        config.addSearchPath(LUT_DIR)
    interop = (config.getMajorVersion(), config.getMinorVersion()) >= INTEROP_ID_VERSION
    for space in spec.colour_spaces:
        if config.getColorSpace(space.name) is not None:
            raise CamcalError(f"colour space {space.name!r} already exists in the base config")
        aliases = (*space.aliases, space.interop_id) if interop and space.interop_id else space.aliases
        taken = [alias for alias in aliases if config.getColorSpace(alias) is not None]
        if taken:
            raise CamcalError(f"alias {taken[0]!r} of colour space {space.name!r} already names a space in the "
                              f"config (rename the camera)")
        cs = ocio.ColorSpace(referenceSpace=ocio.REFERENCE_SPACE_SCENE, name=space.name, family=space.family,
                             encoding=space.encoding, description=space.description,
                             categories=list(space.categories), aliases=list(aliases))
        if interop and space.interop_id:
            cs.setInteropID(space.interop_id)
        cs.setTransform(ocio.GroupTransform(list(space.to_reference)), ocio.COLORSPACE_DIR_TO_REFERENCE)
        config.addColorSpace(cs)
    for look in spec.looks:
        add_look(config, look)
    try:
        config.validate()
    except ocio.Exception as error:
        raise CamcalError(f"the OCIO config does not validate: {error}") from None
    return config
