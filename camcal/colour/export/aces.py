"""The ACES hand-off of a characterisation: its input transform, named by an ACES transform ID, as CLF.

:func:`input_transform` describes a camera's input transform from code
values (normalised to [0, 1]) to ACES2065-1 (an Input Transform, a.k.a.
IDT) or ACEScg: the fit's linearisation, its model (an exact matrix, or the
baked log-chromaticity Lut3D the OCIO export writes) and the matrix from
the fit's XYZ to the ACES space (:func:`camcal.colour.export.ocio_fit.fit_transforms`,
the same transforms as the OCIO colour space and ``colour apply``).
:func:`clf_text` writes it as a Common LUT Format ``ProcessList`` with OCIO's
own writer, carrying the ACES metadata in ``Info`` (``ACEStransformID``,
``ACESuserName``, then the camera, chart, light and fit) and the same facts
in words in ``Description``. The AMF that names it and the DaVinci Resolve
DCTL of the same transform are :mod:`camcal.colour.export.amf` and
:mod:`camcal.colour.export.dctl`; :mod:`camcal.io.aces` writes the files.

The transform ID follows the ACES Transform ID specification (ACES 2):
``urn:ampas:aces:transformId:v2.0:Input.camcal.<Name>.a2.v1`` with the
TransformType ``Input`` (a transform from camera data to ACES2065-1, "user
created or custom transforms intended for specific illuminants"), the
namespace of its creator (``camcal``), a name of the device (the camera's
make and model first when a raw capture records them, as the specification
asks of a creator that is not the maker), its light and its target, without
spaces or periods; ``a2`` the ACES major version and ``v1`` the transform's
own version.

References
----------
- SMPTE ST 2136-1 / Academy S-2014-006: Common LUT Format (CLF), the
  ``ProcessList``'s ``Info`` element (``ACEStransformID``, ``ACESuserName``).
- ACES Transform IDs and User Names (ACES 2 documentation, formerly Academy
  S-2014-002 and TB-2014-002).
- SMPTE ST 2065-1: ACES2065-1 (AP0 primaries, the ACES white).
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from camcal.base.errors import CamcalError
from camcal.colour.bake.transforms import CLF_FORMAT, LUT_SIZES, BakedTransform, apply_cpu, cpu_processor, ocio_module
from camcal.colour.chart.linearise import Linearisation
from camcal.colour.difference import DeltaEStats
from camcal.colour.export.ocio_config import linearisation_transforms
from camcal.colour.export.ocio_fit import fit_transforms, illuminant_label, maker_family, output_matrix
from camcal.colour.fit.record import ColourFit

__all__ = [
    "TRANSFORM_ID_URN",
    "ACES_MAJOR_VERSION",
    "NAMESPACE",
    "ACES_SPACES",
    "id_token",
    "transform_id",
    "InputTransform",
    "input_transform",
    "clf_text",
]

TRANSFORM_ID_URN = "urn:ampas:aces:transformId:v2.0"
ACES_MAJOR_VERSION = 2
NAMESPACE = "camcal"
#: The ACES spaces an input transform may end in, and the token its transform ID names them by.
ACES_SPACES = {"ACES2065-1": "ACES", "ACEScg": "ACEScg"}


def id_token(text: str) -> str:
    """``text`` as a transform ID token: ASCII letters, digits, ``_`` and ``-``, no spaces or periods.

    Examples
    --------
    >>> id_token("Nikon D5100 (D65) v1.2")
    'Nikon_D5100_D65_v1_2'
    """
    return re.sub(r"[^A-Za-z0-9-]+", "_", text).strip("_")


def _device(camera: str, fit: ColourFit) -> str:
    """The camera's name with the raw capture's make and model first, unless the name already holds them."""
    capture = fit.capture or {}
    maker = maker_family(fit).removeprefix("Input/") if capture.get("make") else ""
    words = [w for w in (maker, str(capture.get("model") or "")) if w and w.lower() not in camera.lower()]
    return " ".join([*words, camera])


def transform_id(camera: str, fit: ColourFit, space: str = "ACES2065-1", version: int = 1) -> str:
    """The ACES transform ID of a camera's input transform.

    ``urn:ampas:aces:transformId:v2.0:Input.camcal.<device>_<light>_to_<ACES|ACEScg>.a2.v<version>``,
    ``<light>`` the light the fit is for (:func:`illuminant_label`).

    Examples
    --------
    >>> from types import SimpleNamespace
    >>> fit = SimpleNamespace(capture={"make": "NIKON CORPORATION", "model": "D5100"}, illuminant_change=None,
    ...                       training_illuminant="D65")
    >>> transform_id("left", fit)
    'urn:ampas:aces:transformId:v2.0:Input.camcal.Nikon_D5100_left_D65_to_ACES.a2.v1'
    """
    if space not in ACES_SPACES:
        raise CamcalError(f"unknown ACES space {space!r}, expected one of: {', '.join(ACES_SPACES)}")
    light = illuminant_label(fit)
    device = _device(camera, fit)
    name = id_token(f"{device} {light}" if light and not device.endswith(f"({light})") else device)
    if not name:
        raise CamcalError(f"camera name {camera!r} has no letters or digits to name its ACES transform by")
    return f"{TRANSFORM_ID_URN}:Input.{NAMESPACE}.{name}_to_{ACES_SPACES[space]}.a{ACES_MAJOR_VERSION}.v{version}"


@dataclass(frozen=True, eq=False)
class InputTransform:
    """A camera's input transform to an ACES space, with the metadata its files carry.

    Attributes
    ----------
    transform_id, user_name
        The ACES transform ID (:func:`transform_id`) and the name a user
        interface shows.
    camera, space
        The camera name and the ACES space (``ACES2065-1`` or ``ACEScg``).
    steps
        The OCIO transforms from code values to ``space``, in order (empty
        when the model was not baked: a DCTL needs only the model).
    linearisation
        The fit's per-channel curves (code values to linear camera RGB).
    model
        The fit's model (linear camera RGB to XYZ under its target white).
    baked
        The model as OCIO transforms: ``kind`` ``"matrix"`` (exact) or
        ``"lut3d"`` (baked, with its ``bake_error``); ``None`` when not baked.
    output
        ``(3, 3)``: the fit's XYZ (target white) to ``space``.
    linearisation_error
        Relative error of a sampled linearisation (0 when exact).
    description
        The transform in words (camera, chart, light, model, held-out error).
    metadata
        ``(element, text)`` pairs: what a CLF's ``Info`` holds after the ACES elements.
    """

    transform_id: str
    user_name: str
    camera: str
    space: str
    steps: tuple
    linearisation: Linearisation
    model: Any
    baked: BakedTransform | None
    output: np.ndarray
    linearisation_error: float
    description: str
    metadata: tuple[tuple[str, str], ...]

    @property
    def kind(self) -> str:
        """``"matrix"`` (exact), ``"lut3d"`` (baked) or ``"not baked"``."""
        return self.baked.kind if self.baked is not None else "not baked"

    @property
    def bake_error(self) -> DeltaEStats | None:
        """CIEDE2000 of the baked model over the chart gamut and plausible surfaces (``None``: exact)."""
        return self.baked.bake_error if self.baked is not None else None

    def apply(self, codes: Any) -> np.ndarray:
        """Code values ``(N, 3)`` to ``space`` through OCIO's CPU processor of :attr:`steps` (float32 maths)."""
        if self.baked is None:
            raise CamcalError("this input transform was built without its OCIO transforms (bake=False)")
        return apply_cpu(cpu_processor(ocio_module().GroupTransform(list(self.steps))), codes)

    def summary(self) -> str:
        """One line: the ID, the target, the model and how exact it is."""
        if self.kind == "matrix":
            how = "exact matrix"
        elif self.baked is None:
            how = f"{self.model.label} inlined, not baked"
        else:
            how = (f"{self.baked.lut_size}^3 Lut3D, bake error CIEDE2000 mean {self.bake_error.mean:.3f}, max "
                   f"{self.bake_error.max:.3f}")
        return f"ACES input transform {self.transform_id} ({self.camera} to {self.space}, {how})"


def _metadata(fit: ColourFit, camera: str, space: str, cat: str) -> tuple[tuple[str, str], ...]:
    capture = fit.capture or {}
    evaluation = fit.evaluation or {}
    items = [("Camera", camera), ("CameraMake", capture.get("make")), ("CameraModel", capture.get("model")),
             ("Chart", fit.reference), ("ShotUnder", fit.training_illuminant),
             ("MadeFor", (fit.illuminant_change or {}).get("for_illuminant")),
             ("TargetWhite", fit.target_white), ("Adaptation", f"{cat} to the ACES white, then XYZ to {space}"),
             ("Model", fit.model.label), ("Linearisation", fit.linearisation.label),
             ("TrainingPatches", str(fit.n_patches))]
    for key, element in (("train", "DeltaE2000Training"), ("loo", "DeltaE2000LeaveOneOut"),
                         ("test", "DeltaE2000Test")):
        stats = evaluation.get(key)
        if stats:
            items.append((element, f"mean {stats['mean']:.3f}, p95 {stats['p95']:.3f}, max {stats['max']:.3f}, "
                                   f"n {stats['n']}"))
    provenance = fit.provenance or {}
    items += [("FitCreated", provenance.get("created")), ("FitTool", provenance.get("tool"))]
    return tuple((element, str(text)) for element, text in items if text)


def input_transform(
    fit: ColourFit,
    camera: str,
    *,
    space: str = "ACES2065-1",
    cat: str = "Bradford",
    max_delta_E: float = 0.2,
    lut_sizes: Sequence[int] = LUT_SIZES,
    bake: bool = True,
) -> InputTransform:
    """A characterisation as an ACES input transform: code values to ``space``.

    Parameters
    ----------
    fit
        The characterisation (``colour fit``).
    camera
        The camera's name (in the transform ID and the metadata).
    space
        ``"ACES2065-1"`` (an Input Transform proper) or ``"ACEScg"``.
    cat
        Chromatic adaptation from the fit's target white to the ACES white
        (``"Bradford"``, as OCIO's ACES configs, or ``"CAT02"``).
    max_delta_E, lut_sizes
        The bake of a non-matrix model (:func:`camcal.colour.export.ocio_fit.bake_fit`).
    bake
        Build the OCIO transforms (what a CLF holds); ``False``: the model
        only (what a DCTL holds), nothing baked.

    Returns
    -------
    InputTransform

    Notes
    -----
    ``ACES = M_out (model(L(codes)))`` with ``L`` the linearisation and
    ``M_out = M_XYZ->AP0 @ CAT(target white -> ACES white)``
    (:func:`camcal.colour.export.ocio_fit.output_matrix`); a matrix model
    ``M`` folds into ``M_out @ M``.
    """
    if space not in ACES_SPACES:
        raise CamcalError(f"unknown ACES space {space!r}, expected one of: {', '.join(ACES_SPACES)}")
    if bake:
        steps, baked, lin_error = fit_transforms(fit, space, cat=cat, max_delta_E=max_delta_E, lut_sizes=lut_sizes)
    else:
        steps, baked, lin_error = [], None, linearisation_transforms(fit.linearisation)[1]
    light = illuminant_label(fit)
    chart = f"the {fit.reference} chart" if fit.reference else "a chart"
    shot = f"shot under {fit.training_illuminant}" + (f", for {light}" if fit.illuminant_change else "")
    if baked is None:
        how = "its own terms"
    elif baked.kind == "matrix":
        how = "an exact matrix"
    else:
        how = f"a {baked.lut_size}^3 Lut3D (bake error CIEDE2000 max {baked.bake_error.max:.3f})"
    description = (f"Input transform of camera {camera}: camera code values (normalised to 0-1) to {space}. camcal "
                   f"characterisation from {chart} {shot}; model {fit.model.label} as {how}, linearisation "
                   f"{fit.linearisation.label}; XYZ ({fit.target_white}) to {space} with {cat}.")
    device = _device(camera, fit)
    user_name = f"camcal {device}{'' if device.endswith(f'({light})') else f' ({light})'} to {space}"
    return InputTransform(transform_id(camera, fit, space), user_name, camera, space, tuple(steps),
                          fit.linearisation, fit.model, baked, output_matrix(fit.target_white_XYZ, space, cat), lin_error,
                          description, _metadata(fit, camera, space, cat))


def clf_text(transform: InputTransform, app_release: str = "") -> str:
    """The input transform as CLF (SMPTE ST 2136-1) text, written by OCIO's own writer.

    The ``ProcessList``'s ``id`` is the transform ID and its ``name`` the
    user name; ``Description`` says what the transform is, the descriptors
    name its input and output, and ``Info`` holds ``AppRelease``,
    ``ACEStransformID``, ``ACESuserName`` and then the camera, chart, light
    and fit (:attr:`InputTransform.metadata`). OpenColorIO 2.6 writes ST
    2136-1's XML namespace; 2.3-2.5 write the same elements as the Academy's
    CLF 3 (S-2014-006), without a namespace, which those releases read.
    """
    if transform.baked is None:
        raise CamcalError("a CLF holds the OCIO transforms: build the input transform with bake=True")
    ocio = ocio_module()
    group = ocio.GroupTransform(list(transform.steps))
    metadata = group.getFormatMetadata()
    metadata.setID(transform.transform_id)
    metadata.setName(transform.user_name)
    metadata.addChildElement("Description", transform.description)
    metadata.addChildElement("InputDescriptor", f"{transform.camera} camera code values, normalised to 0-1")
    metadata.addChildElement("OutputDescriptor", transform.space)
    metadata.addChildElement("Info", "")
    info = list(metadata.getChildElements())[-1]
    if app_release:
        info.addChildElement("AppRelease", app_release)
    info.addChildElement("ACEStransformID", transform.transform_id)
    info.addChildElement("ACESuserName", transform.user_name)
    for element, text in transform.metadata:
        info.addChildElement(element, text)
    return group.write(CLF_FORMAT, ocio.Config.CreateRaw())
