"""The ``match`` kind of ``*.colour.json``: :class:`ColourMatch` and its checks (the data).

Listed in :data:`camcal.colour.fit.record.KINDS`; the format is documented
in :mod:`camcal.colour.match.routes`; :func:`camcal.io.colourfile.load_match`
reads the file.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from camcal.colour.difference import DeltaEStats
from camcal.colour.fit.record import (
    LinearisedModel,
    check_header,
    check_linearisation,
    check_provenance,
    check_stats,
    model_and_linearisation,
)
from camcal.base.errors import CamcalError
from camcal.base.fields import integer_field, keys_field, matrix_field, number_field, string_field, vector_field
from camcal.base.clock import utc_timestamp
from camcal.colour.chart.linearise import Linearisation
from camcal.colour.fit.models import model_from_dict
from camcal.colour.match.models import Lut3DModel, MATCH_MODELS, MatchModel
from camcal.colour.match.robust import ROBUST_METHODS

__all__ = ["match_provenance", "ColourMatch"]


# --------------------------------------------------------------------------
# The match file


def match_provenance(source: str | None) -> dict:
    from camcal import __version__

    out = {"tool": f"camcal {__version__}", "created": utc_timestamp()}
    if source:
        out["source"] = str(source)
    return out


def _check_match(data: dict) -> None:
    keys_field(data, "colour match", ("format", "version", "kind", "source", "target", "linearisation", "model",
                                 "fit", "evaluation", "provenance"))
    string_field(data["source"], "source", nullable=True)
    string_field(data["target"], "target", nullable=True)
    check_linearisation(data["linearisation"])
    model = data["model"]
    kind = string_field(keys_field(model, "model", ("kind",), ("terms", "coefficients", "size", "domain_min", "domain_max",
                                                     "smoothing", "table"))["kind"], "model.kind", MATCH_MODELS)
    if kind == "lut3d":
        keys_field(model, "model", ("kind", "size", "domain_min", "domain_max", "smoothing", "table"))
        size = integer_field(model["size"], "model.size", 2)
        vector_field(model["domain_min"], "model.domain_min", 3)
        vector_field(model["domain_max"], "model.domain_max", 3)
        number_field(model["smoothing"], "model.smoothing", 0.0)
        matrix_field(model["table"], "model.table", size**3, 3)
    else:
        keys_field(model, "model", ("kind", "terms", "coefficients"))
        terms = model["terms"]
        if not isinstance(terms, list) or not terms:
            raise CamcalError(f"model.terms: expected a non-empty list of term strings, got {terms!r}")
        for i, term in enumerate(terms):
            string_field(term, f"model.terms[{i}]")
        matrix_field(model["coefficients"], "model.coefficients", 3, len(terms))
    fit = keys_field(data["fit"], "fit", ("route", "robust", "n_fit", "n_inliers", "inlier_threshold"))
    string_field(fit["route"], "fit.route", ("chart", "image"))
    string_field(fit["robust"], "fit.robust", ROBUST_METHODS)
    integer_field(fit["n_fit"], "fit.n_fit", 1)
    integer_field(fit["n_inliers"], "fit.n_inliers", 0)
    if fit["inlier_threshold"] is not None:
        number_field(fit["inlier_threshold"], "fit.inlier_threshold", 0.0)
    evaluation = keys_field(data["evaluation"], "evaluation", ("metric", "space", "train", "test", "before",
                                                          "n_test_outliers", "chart"))
    string_field(evaluation["metric"], "evaluation.metric", ("CIE 2000",))
    string_field(evaluation["space"], "evaluation.space")
    check_stats(evaluation["train"], "evaluation.train", nullable=False)
    check_stats(evaluation["test"], "evaluation.test")
    check_stats(evaluation["before"], "evaluation.before")
    if evaluation["n_test_outliers"] is not None:
        integer_field(evaluation["n_test_outliers"], "evaluation.n_test_outliers", 0)
    chart = evaluation["chart"]
    if chart is not None:
        keys_field(chart, "evaluation.chart", ("common_reference", "source_vs_reference", "target_vs_reference"))
        check_stats(chart["common_reference"], "evaluation.chart.common_reference", nullable=False)
        check_stats(chart["source_vs_reference"], "evaluation.chart.source_vs_reference")
        check_stats(chart["target_vs_reference"], "evaluation.chart.target_vs_reference")
    check_provenance(data["provenance"])


def _model_from_block(block: dict) -> MatchModel:
    if block["kind"] == "lut3d":
        size = block["size"]
        return Lut3DModel(np.array(block["table"], dtype=np.float64).reshape(size, size, size, 3),
                          np.array(block["domain_min"]), np.array(block["domain_max"]), float(block["smoothing"]))
    return model_from_dict({**block, "white_preserving": False, "objective": "xyz", "regularisation": 0.0})


@dataclass(frozen=True, eq=False)
class ColourMatch(LinearisedModel):
    """A camera-to-camera colour match: linear source (B) RGB -> linear target (A) RGB.

    ``apply(RGB)`` maps LINEAR camera-B RGB ``(N, 3)`` to camera-A RGB;
    ``linearise(codes)`` turns camera-B code values into linear RGB;
    ``apply_codes`` chains both. ``matrix`` is the exact 3x3 matrix of a
    ``matrix3x3`` match (``A = matrix @ B``), ``None`` for other models.
    ``fit``, ``evaluation`` and ``provenance`` are the file's plain
    dictionaries (see the module docstring).
    """

    model: Any
    evaluation: dict
    fit: dict
    source: str | None = None
    target: str | None = None
    linearisation: Linearisation = field(default_factory=Linearisation.identity)
    provenance: dict = field(default_factory=dict)

    kind = "match"

    @property
    def matrix(self) -> np.ndarray | None:
        """The 3x3 matrix of a matrix3x3 match (rows R, G, B of the target), else ``None``."""
        if self.model.kind != "matrix3x3":
            return None
        return np.array(self.model.M)

    def to_dict(self) -> dict:
        """The file's JSON object."""
        model = self.model.to_dict()
        if model["kind"] != "lut3d":
            model = {key: model[key] for key in ("kind", "terms", "coefficients")}
        return {
            "format": "camcal.colour",
            "version": 1,
            "kind": "match",
            "source": self.source,
            "target": self.target,
            "linearisation": self.linearisation.to_dict(),
            "model": model,
            "fit": self.fit,
            "evaluation": self.evaluation,
            "provenance": dict(self.provenance) or match_provenance(None),
        }

    @classmethod
    def from_dict(cls, data: dict) -> ColourMatch:
        """Validate a file's JSON object and build the match (errors name the field)."""
        check_header(data, "match")
        _check_match(data)
        model, linearisation = model_and_linearisation(data, _model_from_block)
        return cls(model=model, evaluation=data["evaluation"], fit=data["fit"], source=data["source"],
                   target=data["target"], linearisation=linearisation, provenance=dict(data["provenance"]))

    def summary(self) -> str:
        """A few human lines: which way, model, fit, CIEDE2000."""
        ev = self.evaluation
        lines = [f"match {self.source or 'B'} -> {self.target or 'A'}: {self.model.label} "
                 f"({self.fit['route']} route, robust {self.fit['robust']}, "
                 f"{self.fit['n_inliers']} / {self.fit['n_fit']} samples kept)"]
        if ev["chart"] is not None:
            lines.append(f"CIEDE2000 camera-to-camera via XYZ: {DeltaEStats(**ev['chart']['common_reference'])}")
            for key, name in (("source_vs_reference", self.source or "B"), ("target_vs_reference", self.target or "A")):
                if ev["chart"][key] is not None:
                    lines.append(f"CIEDE2000 {name} vs reference: {DeltaEStats(**ev['chart'][key])}")
        for key, name in (("before", "before matching"), ("train", "after, fit data"), ("test", "after, held out")):
            if ev[key] is not None:
                lines.append(f"CIEDE2000 {name}: {DeltaEStats(**ev[key])}")
        if ev["n_test_outliers"] is not None:
            lines.append(f"held-out outliers (beyond the fit's threshold): {ev['n_test_outliers']}")
        return "\n".join(lines)
