"""Characterisation: patches (camera RGB beside reference XYZ) to a :class:`ColourFit`.

Steps of ``colour fit``:

1. :func:`camcal.pipelines.colour.patches_from_chart` (or
   :func:`camcal.colour.chart.detect.patches_from_image` on an image array):
   detect the chart (cv2.mcc or four manual corners), sample every patch,
   drop clipped patches, pair the code values with the reference chart's XYZ.
2. :func:`characterise`: fit the linearisation on the neutral patches
   (or take the one given), adapt the reference to the target white if
   asked, fit the model (``auto`` picks by leave-one-out, see
   :mod:`camcal.colour.fit.select`), evaluate CIEDE2000 on training,
   leave-one-out and an independent set, and build the :class:`ColourFit`.
3. :func:`camcal.report.characterisation.write_report`: per-patch tables,
   the ``auto`` candidate table and the plots.

Encodings: the RGB of a patch set handed to :func:`characterise` are code
values when a linearisation is fitted or given, linear RGB otherwise; an
independent patch set is in the same encoding as the training set.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from camcal.base.errors import CamcalError
from camcal.base.clock import utc_timestamp
from camcal.colour.bake.samples import bake_model
from camcal.colour.chart.linearise import Linearisation, fit_linearisation
from camcal.colour.chart.patches import PatchSet
from camcal.colour.difference import XYZ_to_Lab
from camcal.colour.fit.evaluate import ColourFitResult, evaluate_model
from camcal.colour.fit.record import ColourFit
from camcal.colour.fit.select import Selection, fitter, select_model
from camcal.colour.fit.synthetic import SyntheticSets, synthesise_from_chart
from camcal.colour.fit.terms import parse_model_spec
from camcal.colour.spectral.data import adapt_XYZ, illuminant_white_XYZ

__all__ = ["Characterisation", "white_from_name", "neutral_indices", "characterise"]


def white_from_name(text: str) -> tuple[str, np.ndarray]:
    """A white from a CIE illuminant name (``D50``) or chromaticity ``x,y``.

    Returns
    -------
    name, XYZ
        XYZ with Y = 1.
    """
    text = str(text).strip()
    if "," in text:
        try:
            x, y = (float(v) for v in text.split(","))
        except ValueError:
            raise CamcalError(f"white {text!r}: expected a CIE name or 'x,y'") from None
        if not (0 < x < 1 and 0 < y < 1 and x + y < 1):
            raise CamcalError(f"white {text!r}: chromaticity out of range")
        return f"x={x:g},y={y:g}", np.array([x / y, 1.0, (1 - x - y) / y])
    return text, illuminant_white_XYZ(text)


def neutral_indices(XYZ: Any, white_XYZ: Any, chroma: float = 4.0) -> np.ndarray:
    """Indices of patches whose reference CIELAB chroma is below ``chroma``."""
    Lab = XYZ_to_Lab(XYZ, white_XYZ)
    return np.flatnonzero(np.hypot(Lab[:, 1], Lab[:, 2]) < chroma)


@dataclass(frozen=True, eq=False)
class Characterisation:
    """The outcome of :func:`characterise`.

    ``train`` and ``test`` hold LINEAR camera RGB and XYZ in the target
    white; ``result`` the per-patch CIEDE2000; ``selection`` what ``auto``
    compared (``None`` for a named model).
    """

    fit: ColourFit
    result: ColourFitResult
    train: PatchSet
    test: PatchSet | None
    selection: Selection | None
    synthetic: SyntheticSets | None = None

    def summary(self) -> str:
        """A few human lines: model, why, and CIEDE2000 on each set."""
        lines = [f"model: {self.result.model.label} ({self.fit.model.to_dict().get('objective')}"
                 + (f", lambda {self.fit.model.regularisation:g})" if hasattr(self.fit.model, "regularisation")
                    else f", smoothing {self.fit.model.smoothing:g})")]
        if self.synthetic is not None:
            lines.append(f"spectral route: {self.synthetic.describe()}")
        if self.selection is not None:
            lines.append(f"auto picked it: {self.selection.reason}")
            lines.append("ranking (best score first):")
            lines.extend(self.selection.ranking())
        lines.append(f"linearisation: {self.fit.linearisation.label}"
                     + (f" (neutral residual {100 * self.fit.linearisation.residual:.2f} %)"
                        if self.fit.linearisation.residual is not None else ""))
        lines.append(f"CIEDE2000 training:      {self.result.stats_train}")
        if self.result.stats_loo is not None:
            lines.append(f"CIEDE2000 leave-one-out: {self.result.stats_loo}")
        if self.result.stats_test is not None:
            lines.append(f"CIEDE2000 independent:   {self.result.stats_test}")
        return "\n".join(lines)


def _export_check(white_XYZ: np.ndarray, reference: str | None, illuminant: str):
    """``auto``'s exportability check: the exporters' own bake of a candidate model (every Lut3D size, as they do)."""
    def exportable(model) -> float | None:
        baked = bake_model(model, white_XYZ, reference=reference, illuminant=illuminant)
        return None if baked.bake_error is None else baked.bake_error.max

    return exportable


def characterise(
    train: PatchSet,
    *,
    white: str = "D50",
    model: str = "auto",
    objective: str | None = None,
    regularisation: float = 0.0,
    linearise: str | Linearisation = "none",
    test: PatchSet | None = None,
    target_white: str | None = None,
    adaptation: str = "Bradford",
    camera: str | None = None,
    reference: str | None = None,
    source: str | None = None,
    loo: bool = True,
    candidates: Sequence[str] | None = None,
    spectra: str | None = None,
    illuminant: str | None = None,
) -> Characterisation:
    """Fit and evaluate a characterisation.

    Parameters
    ----------
    train
        Training patches: camera RGB (code values when ``linearise`` is not
        ``"none"``) and XYZ relative to ``white`` (perfect white Y = 1);
        their ``weights`` (a chart photo's signal-to-noise weights) weigh
        every fit, leave-one-out refit and ``auto``'s ranking.
    white
        Training illuminant: CIE name or ``"x,y"``.
    model
        ``"auto"`` or a model name (``"root-polynomial:2"``...).
    objective
        ``"xyz"`` or ``"de2000"``; ``None`` means ``xyz`` for a named
        model and both for ``auto``.
    regularisation
        Ridge ``lambda`` on the non-linear terms of a named model (``auto``
        chooses its own).
    linearise
        ``"none"``, ``"gamma-offset"``, ``"lut1d"``, ``"named:FUNCTION"``
        (fitted on the neutral patches) or a :class:`Linearisation`.
    test
        Independent patches, same encoding and white as ``train``.
    target_white
        White of the output XYZ; ``None`` keeps ``white``. When it differs,
        reference XYZ are adapted with ``adaptation`` (Bradford or CAT02;
        Bradford by default, as the OCIO export and the command line).
    camera, reference, source
        Recorded in the file.
    loo
        Compute leave-one-out figures (always on for ``auto``).
    candidates
        Models ``auto`` may pick (default: :func:`camcal.colour.fit.select.select_model`'s list).
    spectra
        The chart's spectral data (``BabelColor Average``...; patch names
        must match): with ``auto``, sensitivities are estimated from the
        chart and reflectance sets rendered through them
        (:mod:`camcal.colour.fit.synthetic`): candidates are scored on 300
        held-out Munsell colours and also trained on the 99 CIE 2017 samples
        and 300 other Munsell colours (the spectral route); the chart's RGB
        must be linear (or linearised).
    illuminant
        CIE name of the chart's light for ``spectra`` (default: ``white``).

    Returns
    -------
    Characterisation
    """
    white_name, white_XYZ = white_from_name(white)
    if target_white is None:
        target_name, target_XYZ, adapt = white_name, white_XYZ, None
    else:
        target_name, target_XYZ = white_from_name(target_white)
        adapt = None if np.allclose(target_XYZ, white_XYZ, atol=1e-6) else adaptation
    if objective is not None and objective not in ("xyz", "de2000"):
        raise CamcalError(f"unknown objective {objective!r}, expected one of: xyz, de2000")

    if isinstance(linearise, Linearisation):
        linearisation = linearise
    else:
        if linearise == "none":
            linearisation = Linearisation.identity()
        else:
            neutral = neutral_indices(train.XYZ, white_XYZ)
            if neutral.size < 3 and not linearise.startswith("named"):
                raise CamcalError(
                    f"linearisation {linearise!r} needs at least 3 neutral patches, found {neutral.size}"
                )
            linearisation = fit_linearisation(train.RGB[neutral], train.XYZ[neutral, 1], linearise)

    def prepare(patches: PatchSet) -> PatchSet:
        XYZ = patches.XYZ if adapt is None else adapt_XYZ(patches.XYZ, white_XYZ, target_XYZ, adapt)
        return PatchSet(patches.names, linearisation.apply(patches.RGB), XYZ, patches.weights)

    train_lin = prepare(train)
    test_lin = prepare(test) if test is not None else None
    RGB, XYZ = train_lin.RGB, train_lin.XYZ

    selection = None
    synthetic = None
    validation = spectral = None
    if spectra is not None and model == "auto":
        synthetic = synthesise_from_chart(train_lin, spectra, illuminant or white_name)

        def target(XYZ_s: np.ndarray) -> np.ndarray:
            return XYZ_s if adapt is None else adapt_XYZ(XYZ_s, white_XYZ, target_XYZ, adapt)

        validation = (synthetic.held_out.RGB, target(synthetic.held_out.XYZ))
        spectral = (synthetic.training.RGB, target(synthetic.training.XYZ))
    if model == "auto":
        objectives = ("xyz", "de2000") if objective is None else (objective,)
        selection = select_model(RGB, XYZ, target_XYZ, objectives=objectives, candidates=candidates,
                                 exportable=_export_check(target_XYZ, reference, white_name),
                                 weights=train.weights, validation=validation, spectral=spectral)
        spec = selection.picked.spec
        chosen_objective = selection.picked.objective
        regularisation = selection.picked.regularisation
        shrinkage = selection.picked.shrinkage
    else:
        shrinkage = 0.0
        spec = parse_model_spec(model)
        chosen_objective = objective or "xyz"
        if not (np.isfinite(regularisation) and regularisation >= 0):
            raise CamcalError(f"regularisation must be a finite number >= 0, got {regularisation}")

    RGB_white = None
    if spec.white_preserving:
        neutral = neutral_indices(XYZ, target_XYZ)
        if neutral.size == 0:
            raise CamcalError(f"{spec.label} needs neutral patches to find the camera white, found none")
        Y = XYZ[neutral, 1]
        RGB_white = (Y @ RGB[neutral]) / (Y @ Y)

    extra = spectral if selection is not None and selection.picked.training == "spectral" else None
    fit = fitter(spec, chosen_objective, regularisation, target_XYZ, extra, RGB_white, shrinkage)

    result = evaluate_model(
        fit, RGB, XYZ, target_XYZ,
        test=None if test_lin is None else (test_lin.RGB, test_lin.XYZ),
        loo=loo or selection is not None,
        weights=train.weights,
    )
    from camcal import __version__

    provenance = {"tool": f"camcal {__version__}",
                  "created": utc_timestamp()}
    if source:
        provenance["source"] = str(source)
    colour_fit = ColourFit(
        linearisation=linearisation,
        model=result.model,
        training_illuminant=white_name,
        training_white_XYZ=tuple(float(v) for v in white_XYZ),  # type: ignore[arg-type]
        target_white=target_name,
        target_white_XYZ=tuple(float(v) for v in target_XYZ),  # type: ignore[arg-type]
        evaluation=result.evaluation_dict(),
        n_patches=len(train),
        camera=camera,
        reference=reference,
        adaptation=adapt,
        selection=None if selection is None else selection.to_dict(),
        provenance=provenance,
    )
    return Characterisation(colour_fit, result, train_lin, test_lin, selection, synthetic)
