"""The colour fit record: what a ``*.colour.json`` holds, as data (``to_dict`` / ``from_dict``).

Exporters (OCIO colour space, ICC input profile) and the camera-to-camera
match read only this file. It is JSON, versioned, validated on load (one
error naming the bad field; unknown keys are rejected), written atomically
(temporary file + rename) and round-trips exactly (floats are written with
Python's shortest repr, which reads back to the same double). Reading and
writing the file: :mod:`camcal.io.colourfile` (``load_fit``,
``load_colour_file``, ``save_colour_file``).

Format, version 1, kind ``characterisation``::

    {
      "format": "camcal.colour",
      "version": 1,
      "kind": "characterisation",
      "camera": "A7S-left" | null,
      "linearisation": {
        "channels": [CURVE_R, CURVE_G, CURVE_B],    # code values -> linear
        "residual": 0.004                           # optional: RMS relative
      },                                            # error on the neutrals
      "model": MODEL,                               # linear RGB -> XYZ
      "training": {
        "illuminant": "D50",         # what the reference XYZ were under
        "white_XYZ": [0.9642, 1.0, 0.8249],
        "reference": "ColorChecker24 - After November 2014" | null,
        "n_patches": 24,
        "selection": null | {"method": str, "picked": CANDIDATE,
                             "reason": str, "candidates": [CANDIDATE...]},
        "illuminant_change": {...}   # optional: a fit made for another light
      },                             # (camcal.colour.fit.illuminant): for_illuminant,
                                     # route, reason, candidates [{route, model,
                                     # rms, mean, p95, max}] (model and rms
                                     # optional), the reflectance sets used
      "capture": {...},              # optional: raw metadata (camcal.io.raw):
                                     # make, model, black_level, white_level ...
      "target": {
        "space": "XYZ",
        "white": "D50",                     # the white of the output XYZ
        "white_XYZ": [0.9642, 1.0, 0.8249], # Y of the perfect white = 1
        "adaptation": null | "CAT02" | "Bradford"  # training -> target white
      },
      "evaluation": {
        "metric": "CIE 2000",
        "train": STATS, "loo": STATS | null, "test": STATS | null
      },
      "provenance": {"tool": "camcal 0.1.0", "created": "2026-...Z",
                     "source": "chart.jpg"}     # source optional
    }

``CURVE`` (per channel; code values normalised to [0, 1]):
``{"kind": "none"}``,
``{"kind": "gamma-offset", "gamma": g, "offset": o, "gain": k}``
(``L = k * max(V - o, 0) ** g``),
``{"kind": "lut1d", "domain": [0.0, 1.0], "samples": [...]}`` (uniform
samples, linear interpolation, linear extension beyond the domain),
``{"kind": "named", "function": "sRGB", "scale": s}`` (colour-science's
``CCTF_DECODINGS[function]`` times ``s``).

``MODEL``: for ``matrix3x3``, ``polynomial``, ``root-polynomial``::

    {"kind": "polynomial", "terms": ["R", "G", "B", "R*G", ..., "1"],
     "coefficients": [[...T...], [...T...], [...T...]],   # rows X, Y, Z
     "white_preserving": false, "objective": "xyz" | "de2000" | "xyz+de2000",
     "regularisation": 0.0, "shrinkage": 0.1}

with ``XYZ = coefficients @ terms(RGB)``; root terms read
``"(R*G)^(1/2)"``; ``shrinkage`` (optional, 0 when absent) is the weight of the
3x3 matrix fit blended into the coefficients (``auto`` chooses it). For ``rbf``::

    {"kind": "rbf", "kernel": "polyharmonic-3" | "polyharmonic-1" | "thin-plate",
     "smoothing": 1e-4, "centres": [[R, G, B], ...], "weights": [[X, Y, Z], ...],
     "linear": {"terms": ["R", "G", "B", "1"], "coefficients": 3x4},
     "objective": "xyz"}

with ``XYZ = sum_j weights_j phi(|RGB - centres_j|) + linear @ [R, G, B, 1]``.

``STATS``: ``{"n", "mean", "median", "p90", "p95", "max"}`` of CIEDE2000.
``CANDIDATE``: ``{"model", "objective", "regularisation", "loo_mean",
"loo_p95"}``, plus ``"exportable"`` and ``"bake_error_max"`` (CIEDE2000 of
the baked model; absent for an exact matrix) on the candidates ``auto``
handed to the exporters' check.

Using a fit::

    from camcal.io.colourfile import load_fit
    fit = load_fit("cam.colour.json")
    XYZ = fit.apply(RGB_linear)        # (N, 3) LINEAR camera RGB -> XYZ
    RGB_linear = fit.linearise(codes)  # (N, 3) code values in [0, 1] -> linear
    XYZ = fit.apply_codes(codes)       # both: code values -> XYZ
    # fast: OCIO's CPU processor (float32), camcal.colour.export.ocio_fit.fit_processor
    image = fit_processor(fit, "ACEScg").apply(codes)

XYZ is relative to the target white, Y = 1 for the perfect white.
Every ``kind`` is listed in :data:`KINDS`; :data:`camcal.io.colourfile.FILE_KINDS`
names the class whose ``from_dict`` reads each: nothing registers itself as
a side effect of an import.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from camcal.base.errors import CamcalError
from camcal.base.fields import boolean_field as _boolean
from camcal.base.fields import integer_field as _integer
from camcal.base.fields import keys_field as _keys
from camcal.base.fields import matrix_field as _matrix
from camcal.base.fields import number_field as _number
from camcal.base.fields import string_field as _string
from camcal.base.fields import vector_field as _vector
from camcal.colour.chart.linearise import CURVE_KINDS, Linearisation
from camcal.colour.fit.models import LinearTermsModel, RBFModel, model_from_dict
from camcal.colour.fit.terms import MODEL_KINDS, OBJECTIVES, RBF_KERNELS

__all__ = [
    "FORMAT",
    "VERSION",
    "KINDS",
    "LinearisedModel",
    "ColourFit",
    "check_header",
    "check_linearisation",
    "check_provenance",
    "check_stats",
    "model_and_linearisation",
]

FORMAT = "camcal.colour"
VERSION = 1
#: Every kind of ``*.colour.json`` (the classes reading them: :data:`camcal.io.colourfile.FILE_KINDS`).
KINDS = ("characterisation", "match")


# --------------------------------------------------------------------------
# Schema checking: each helper names the field path in its error (the generic
# ones are camcal.base.fields'; these are the colour file's own, public for the
# other kinds: camcal.colour.match.record).


def check_stats(value: Any, where: str, nullable: bool = True) -> None:
    if value is None and nullable:
        return
    _keys(value, where, ("n", "mean", "median", "p90", "p95", "max"))
    _integer(value["n"], f"{where}.n", 1)
    for key in ("mean", "median", "p90", "p95", "max"):
        _number(value[key], f"{where}.{key}", 0.0)


def _check_curve(value: Any, where: str) -> None:
    kind = _string(_keys(value, where, ("kind",), ("gamma", "offset", "gain", "domain", "samples",
                                                    "function", "scale"))["kind"], f"{where}.kind", CURVE_KINDS)
    required = {"none": (), "gamma-offset": ("gamma", "offset", "gain"), "lut1d": ("domain", "samples"),
                "named": ("function", "scale")}[kind]
    _keys(value, where, ("kind",) + required)
    if kind == "gamma-offset":
        _number(value["gamma"], f"{where}.gamma", 0.0)
        _number(value["offset"], f"{where}.offset")
        _number(value["gain"], f"{where}.gain", 0.0)
    elif kind == "lut1d":
        _vector(value["domain"], f"{where}.domain", 2)
        samples = _vector(value["samples"], f"{where}.samples")
        if len(samples) < 2:
            raise CamcalError(f"{where}.samples: need at least 2 samples")
        if any(b < a for a, b in zip(samples, samples[1:])):
            raise CamcalError(f"{where}.samples: must be non-decreasing")
    elif kind == "named":
        _string(value["function"], f"{where}.function")
        _number(value["scale"], f"{where}.scale")


def _check_model(value: Any, where: str) -> None:
    kind = _string(_keys(value, where, ("kind",), ("terms", "coefficients", "white_preserving", "objective",
                                                    "regularisation", "shrinkage", "kernel", "smoothing",
                                                    "centres", "weights", "linear"))["kind"], f"{where}.kind", MODEL_KINDS)
    if kind == "rbf":
        _keys(value, where, ("kind", "kernel", "smoothing", "centres", "weights", "linear", "objective"))
        _string(value["kernel"], f"{where}.kernel", RBF_KERNELS)
        _number(value["smoothing"], f"{where}.smoothing", 0.0)
        centres = _matrix(value["centres"], f"{where}.centres", None, 3)
        _matrix(value["weights"], f"{where}.weights", len(centres), 3)
        linear = _keys(value["linear"], f"{where}.linear", ("terms", "coefficients"))
        if linear["terms"] != ["R", "G", "B", "1"]:
            raise CamcalError(f"{where}.linear.terms: expected ['R', 'G', 'B', '1'], got {linear['terms']!r}")
        _matrix(linear["coefficients"], f"{where}.linear.coefficients", 3, 4)
        _string(value["objective"], f"{where}.objective", ("xyz",))
        return
    _keys(value, where, ("kind", "terms", "coefficients", "white_preserving", "objective", "regularisation"),
          ("shrinkage",))
    terms = value["terms"]
    if not isinstance(terms, list) or not terms:
        raise CamcalError(f"{where}.terms: expected a non-empty list of term strings, got {terms!r}")
    for i, term in enumerate(terms):
        _string(term, f"{where}.terms[{i}]")
    _matrix(value["coefficients"], f"{where}.coefficients", 3, len(terms))
    _boolean(value["white_preserving"], f"{where}.white_preserving")
    _string(value["objective"], f"{where}.objective", OBJECTIVES)
    _number(value["regularisation"], f"{where}.regularisation", 0.0)
    if "shrinkage" in value:
        _shrinkage(value["shrinkage"], f"{where}.shrinkage")


def _shrinkage(value: Any, where: str) -> None:
    if _number(value, where, 0.0) >= 1.0:
        raise CamcalError(f"{where}: must be < 1, got {value!r}")


def _check_candidate(value: Any, where: str) -> None:
    _keys(value, where, ("model", "objective", "regularisation", "loo_mean", "loo_p95"),
          ("exportable", "bake_error_max", "score", "score_se", "validation_mean", "training", "shrinkage"))
    if "training" in value:
        _string(value["training"], f"{where}.training", ("chart", "spectral"))
    if "shrinkage" in value:
        _shrinkage(value["shrinkage"], f"{where}.shrinkage")
    for key in ("score", "score_se", "validation_mean"):
        if key in value:
            _number(value[key], f"{where}.{key}", 0.0)
    if "exportable" in value:
        _boolean(value["exportable"], f"{where}.exportable")
    if "bake_error_max" in value:
        _number(value["bake_error_max"], f"{where}.bake_error_max", 0.0)
    _string(value["model"], f"{where}.model")
    _string(value["objective"], f"{where}.objective", OBJECTIVES)
    _number(value["regularisation"], f"{where}.regularisation", 0.0)
    _number(value["loo_mean"], f"{where}.loo_mean", 0.0)
    _number(value["loo_p95"], f"{where}.loo_p95", 0.0)


def check_linearisation(value: Any) -> None:
    lin = _keys(value, "linearisation", ("channels",), ("residual",))
    if not isinstance(lin["channels"], list) or len(lin["channels"]) != 3:
        raise CamcalError("linearisation.channels: expected 3 curves (R, G, B)")
    for i, curve in enumerate(lin["channels"]):
        _check_curve(curve, f"linearisation.channels[{i}]")
    if "residual" in lin:
        _number(lin["residual"], "linearisation.residual", 0.0)


def check_provenance(value: Any) -> None:
    provenance = _keys(value, "provenance", ("tool", "created"), ("source",))
    for key in provenance:
        _string(provenance[key], f"provenance.{key}")


def model_and_linearisation(data: dict, read_model: Callable[[dict], Any]) -> tuple[Any, Linearisation]:
    """Build a checked file's model and linearisation; errors start with the field."""
    try:
        return read_model(data["model"]), Linearisation.from_dict(data["linearisation"])
    except CamcalError as error:
        message = str(error)
        if not message.startswith(("model", "linearisation")):
            message = f"model: {message}"
        raise CamcalError(message) from None


ILLUMINANT_CHANGE_KEYS = ("for_illuminant", "route", "training_reflectances", "validation_reflectances",
                          "plausible_cameras", "sensitivities", "reason", "candidates")
CAPTURE_KEYS = ("format", "make", "model", "black_level", "white_level", "cfa_pattern", "demosaic",
                "saturated_fraction")


def _check_characterisation(data: dict) -> None:
    _keys(data, "colour fit", ("format", "version", "kind", "camera", "linearisation", "model", "training",
                               "target", "evaluation", "provenance"), ("capture",))
    if "capture" in data:
        _keys(data["capture"], "capture", ("format", "make", "model"), CAPTURE_KEYS)
    _string(data["camera"], "camera", nullable=True)
    check_linearisation(data["linearisation"])
    _check_model(data["model"], "model")
    training = _keys(data["training"], "training", ("illuminant", "white_XYZ", "reference", "n_patches", "selection"),
                     ("illuminant_change",))
    if "illuminant_change" in training:
        change = _keys(training["illuminant_change"], "training.illuminant_change", ILLUMINANT_CHANGE_KEYS)
        _string(change["for_illuminant"], "training.illuminant_change.for_illuminant")
        _string(change["route"], "training.illuminant_change.route")
        if not isinstance(change["candidates"], list):
            raise CamcalError("training.illuminant_change.candidates: expected a list")
        for i, c in enumerate(change["candidates"]):
            _keys(c, f"training.illuminant_change.candidates[{i}]", ("route", "mean", "p95", "max"), ("model", "rms"))
            for key in ("mean", "p95", "max", "rms"):
                if key in c:
                    _number(c[key], f"training.illuminant_change.candidates[{i}].{key}", 0.0)
            if "model" in c:
                _string(c["model"], f"training.illuminant_change.candidates[{i}].model")
    _string(training["illuminant"], "training.illuminant")
    _vector(training["white_XYZ"], "training.white_XYZ", 3)
    _string(training["reference"], "training.reference", nullable=True)
    _integer(training["n_patches"], "training.n_patches", 1)
    selection = training["selection"]
    if selection is not None:
        _keys(selection, "training.selection", ("method", "picked", "reason", "candidates"))
        _string(selection["method"], "training.selection.method")
        _string(selection["reason"], "training.selection.reason")
        _check_candidate(selection["picked"], "training.selection.picked")
        if not isinstance(selection["candidates"], list):
            raise CamcalError("training.selection.candidates: expected a list")
        for i, c in enumerate(selection["candidates"]):
            _check_candidate(c, f"training.selection.candidates[{i}]")
    target = _keys(data["target"], "target", ("space", "white", "white_XYZ", "adaptation"))
    _string(target["space"], "target.space", ("XYZ",))
    _string(target["white"], "target.white")
    white = _vector(target["white_XYZ"], "target.white_XYZ", 3)
    if abs(white[1] - 1.0) > 1e-9:
        raise CamcalError(f"target.white_XYZ: Y of the white must be 1, got {white[1]!r}")
    _string(target["adaptation"], "target.adaptation", ("CAT02", "Bradford"), nullable=True)
    evaluation = _keys(data["evaluation"], "evaluation", ("metric", "train", "loo", "test"))
    _string(evaluation["metric"], "evaluation.metric", ("CIE 2000",))
    check_stats(evaluation["train"], "evaluation.train", nullable=False)
    check_stats(evaluation["loo"], "evaluation.loo")
    check_stats(evaluation["test"], "evaluation.test")
    check_provenance(data["provenance"])


# --------------------------------------------------------------------------


class LinearisedModel:
    """Shared methods of the colour files' objects (need ``linearisation``, ``model``, ``to_dict``).

    ``linearise(codes)``: code values ``(N, 3)`` in [0, 1] to linear camera
    RGB; ``apply(RGB)``: LINEAR camera RGB ``(N, 3)`` through the model
    (XYZ for a characterisation, the other camera's RGB for a match);
    ``apply_codes(codes)``: both, ``apply(linearise(codes))``; equality
    compares the files' contents (:func:`camcal.io.colourfile.save_colour_file`
    writes one).
    """

    linearisation: Linearisation
    model: Any

    def linearise(self, codes: Any) -> np.ndarray:
        """Code values ``(N, 3)`` in [0, 1] to linear camera RGB ``(N, 3)``."""
        return self.linearisation.apply(codes)

    def apply(self, RGB: Any) -> np.ndarray:
        """LINEAR camera RGB ``(N, 3)`` through the model, ``(N, 3)``."""
        return self.model.apply(RGB)

    def apply_codes(self, codes: Any) -> np.ndarray:
        """Code values ``(N, 3)`` through linearisation and model: ``apply(linearise(codes))``."""
        return self.apply(self.linearise(codes))

    def __eq__(self, other: object) -> bool:
        return type(other) is type(self) and self.to_dict() == other.to_dict()  # type: ignore[attr-defined]

    __hash__ = None  # type: ignore[assignment]


@dataclass(frozen=True, eq=False)
class ColourFit(LinearisedModel):
    """A camera characterisation: linearisation, model, whites, evaluation.

    ``linearise(codes)`` maps code values (normalised to [0, 1]) to linear
    camera RGB; ``apply(RGB)`` maps LINEAR camera RGB to XYZ relative to
    ``target_white_XYZ`` (Y = 1 for the perfect white); ``apply_codes``
    chains both. The other attributes mirror the file (see the module
    docstring); ``evaluation``, ``selection`` and ``provenance`` are the
    file's plain dictionaries.
    """

    linearisation: Linearisation
    model: LinearTermsModel | RBFModel
    training_illuminant: str
    training_white_XYZ: tuple[float, float, float]
    target_white: str
    target_white_XYZ: tuple[float, float, float]
    evaluation: dict
    n_patches: int
    camera: str | None = None
    reference: str | None = None
    adaptation: str | None = None
    selection: dict | None = None
    provenance: dict = field(default_factory=dict)
    illuminant_change: dict | None = None
    capture: dict | None = None

    kind = "characterisation"

    def to_dict(self) -> dict:
        """The file's JSON object."""
        from camcal import __version__

        provenance = dict(self.provenance) or {"tool": f"camcal {__version__}", "created": ""}
        data = {
            "format": FORMAT,
            "version": VERSION,
            "kind": "characterisation",
            "camera": self.camera,
            "linearisation": self.linearisation.to_dict(),
            "model": self.model.to_dict(),
            "training": {
                "illuminant": self.training_illuminant,
                "white_XYZ": [float(v) for v in self.training_white_XYZ],
                "reference": self.reference,
                "n_patches": int(self.n_patches),
                "selection": self.selection,
            },
            "target": {
                "space": "XYZ",
                "white": self.target_white,
                "white_XYZ": [float(v) for v in self.target_white_XYZ],
                "adaptation": self.adaptation,
            },
            "evaluation": self.evaluation,
            "provenance": provenance,
        }
        if self.illuminant_change is not None:
            data["training"]["illuminant_change"] = self.illuminant_change
        if self.capture is not None:
            data["capture"] = self.capture
        return data

    @classmethod
    def from_dict(cls, data: dict) -> ColourFit:
        """Validate a file's JSON object and build the fit (errors name the field)."""
        check_header(data, "characterisation")
        _check_characterisation(data)
        training, target = data["training"], data["target"]
        model, linearisation = model_and_linearisation(data, model_from_dict)
        return cls(
            linearisation=linearisation,
            model=model,
            training_illuminant=training["illuminant"],
            training_white_XYZ=tuple(training["white_XYZ"]),  # type: ignore[arg-type]
            target_white=target["white"],
            target_white_XYZ=tuple(target["white_XYZ"]),  # type: ignore[arg-type]
            evaluation=data["evaluation"],
            n_patches=training["n_patches"],
            camera=data["camera"],
            reference=training["reference"],
            adaptation=target["adaptation"],
            selection=training["selection"],
            provenance=dict(data["provenance"]),
            illuminant_change=training.get("illuminant_change"),
            capture=data.get("capture"),
        )



def check_header(data: Any, kind: str | None = None) -> str:
    if not isinstance(data, dict):
        raise CamcalError(f"colour fit: expected a JSON object, got {type(data).__name__}")
    if data.get("format") != FORMAT:
        raise CamcalError(f"format: expected {FORMAT!r}, got {data.get('format')!r}")
    if data.get("version") != VERSION or isinstance(data.get("version"), bool):
        raise CamcalError(f"version: this camcal reads version {VERSION}, got {data.get('version')!r}")
    found = data.get("kind")
    if found not in KINDS:
        raise CamcalError(f"kind: expected one of: {', '.join(KINDS)}, got {found!r}")
    if kind is not None and found != kind:
        raise CamcalError(f"kind: expected {kind!r}, got {found!r}")
    return found
