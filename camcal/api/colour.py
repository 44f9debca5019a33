"""``camcal.fit_colour``: camera RGB to CIE XYZ from a chart photo or patches, as ``colour fit``.

(:mod:`camcal.colour` is the pure maths the fit runs on; this module reads the
chart or the patch files, runs the fit with the command's defaults and checks,
and writes the ``*.colour.json`` and the report.)
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from camcal.base.errors import CamcalError

if TYPE_CHECKING:
    from camcal.colour.chart.patches import PatchSet
    from camcal.colour.fit.characterise import Characterisation
    from camcal.pipelines.colour import ChartPatches

__all__ = ["ColourFit", "fit_colour"]

#: The reference chart of ``chart`` by default (colour-science's name).
DEFAULT_REFERENCE = "ColorChecker24 - After November 2014"


@dataclass(frozen=True)
class ColourFit:
    """What :func:`fit_colour` fitted and wrote.

    Attributes
    ----------
    fit : record
        The fit as written (``*.colour.json``; :mod:`camcal.colour.fit.record`): the model, its linearisation,
        the whites and the capture's metadata of a raw chart.
    outcome : Characterisation or the illuminant route's outcome
        How it was judged: CIEDE2000 on the training patches, by leave-one-out and on the test patches (with
        ``for_illuminant``: each route on the validation reflectances); ``summary()`` says it in words.
    n_train : int
        Training patches.
    chart : ChartPatches or None
        With ``chart``: the detection, the patches used, dropped and too dark.
    for_illuminant, validation_reflectances : str or None
        The light the fit is for and the reflectances its routes were compared on (None: the chart's light).
    files : tuple of (Path, str)
        ``(path, kind)`` of the files written: the fit (``colour fit``) and the report's.
    """

    fit: Any
    outcome: Any
    n_train: int
    chart: ChartPatches | None = None
    for_illuminant: str | None = None
    validation_reflectances: str | None = None
    files: tuple[tuple[Path, str], ...] = ()

    def save(self, path: str | os.PathLike) -> Path:
        """Write the fit (``*.colour.json``, atomically); its path."""
        from camcal.io.colourfile import save_colour_file

        return save_colour_file(self.fit, path)

    def lines(self) -> list[str]:
        """The summary ``colour fit`` prints after the fit."""
        return [self.outcome.summary()]

    def figures(self) -> dict[str, Any]:
        """The figures of ``colour fit --json``."""
        import dataclasses

        if self.for_illuminant is not None:
            outcome = self.outcome
            return dict(for_illuminant=self.for_illuminant, route=outcome.picked, model=self.fit.model.label,
                        n_train=self.n_train, reason=outcome.reason, validation_reflectances=self.validation_reflectances,
                        delta_E2000_validation={score.route: score.to_dict() for score in outcome.scores})
        outcome: Characterisation = self.outcome
        stats = {name: None if value is None else dataclasses.asdict(value) for name, value in (
            ("train", outcome.result.stats_train), ("loo", outcome.result.stats_loo),
            ("test", outcome.result.stats_test))}
        figures = dict(model=outcome.result.model.label, linearisation=outcome.fit.linearisation.label,
                       selection=None if outcome.selection is None else outcome.selection.reason,
                       n_train=self.n_train, delta_E2000=stats)
        if self.chart is not None:
            figures.update(n_too_dark=len(self.chart.too_dark), n_dropped=len(self.chart.excluded))
        return figures


def fit_colour(
    patches: str | os.PathLike | PatchSet | None = None,
    *,
    chart: str | os.PathLike | None = None,
    reference: str = DEFAULT_REFERENCE,
    corners: Sequence[Sequence[float]] | str | None = None,
    detector: str = "auto",
    keep_clipped: bool = False,
    model: str = "auto",
    objective: str | None = None,
    regularisation: float = 0.0,
    linearise: str | None = None,
    illuminant: str = "D50",
    target_white: str | None = None,
    adaptation: str = "CAT02",
    spectra: str | None = None,
    test_patches: str | os.PathLike | PatchSet | None = None,
    camera: str | None = None,
    for_illuminant: str | None = None,
    sensitivities: str | os.PathLike | None = None,
    training_reflectances: str = "rawtoaces 190",
    validation_reflectances: str = "Munsell validation",
    plausible_cameras: int = 0,
    out: str | os.PathLike | None = None,
    report: str | os.PathLike | None = None,
    log: Callable[[str], None] | None = None,
) -> ColourFit:
    """Fit camera RGB to CIE XYZ (perfect white Y = 1) and judge it (``camcal colour fit``).

    The fit is judged by CIEDE2000 on the training patches, by leave-one-out
    and on independent ``test_patches``; ``model="auto"`` picks the model,
    objective and regularisation by leave-one-out CIEDE2000 and says why.
    With ``for_illuminant``, the fit is for another light than the chart's
    (the spectral route through ``sensitivities`` against the adapted chart
    fit, compared on validation reflectances).

    Parameters
    ----------
    patches : path or PatchSet, optional
        Training patches: a CSV ``R,G,B,X,Y,Z`` (camera RGB, reference XYZ under ``illuminant``, optional first
        column name). Give this or ``chart``.
    chart : path, optional
        A photo of a 24-patch ColorChecker (PNG / TIFF / JPEG / EXR, or raw: DNG, CR2, NEF, ARW..., read as
        linear camera RGB).
    reference : str
        The chart's reference data (colour-science name or cc24, cc24-2005, babel, sg).
    corners : 4 (x, y) or str, optional
        The patch grid's corners instead of detection: top-left (dark skin), top-right, bottom-right,
        bottom-left; or the command's ``"X,Y,..."`` text.
    detector : {"auto", "segmentation", "cv2.mcc"}
    keep_clipped : bool
        Keep the patches flagged clipped.
    model : str
        ``auto``, ``matrix3x3[:white-preserving]``, ``polynomial:N``, ``root-polynomial:D`` or ``rbf[:KERNEL]``.
    objective : {"xyz", "de2000"}, optional
    regularisation : float
        Ridge lambda on the non-linear terms of a named model.
    linearise : str, optional
        ``none``, ``gamma-offset``, ``lut1d``, ``named:FUNCTION``; default ``lut1d`` for a chart (``none`` for a
        raw one or with ``for_illuminant``), ``none`` for patches.
    illuminant : str
        The white the reference XYZ are relative to (CIE name or ``x,y``).
    target_white : str, optional
        The white of the output XYZ (default: the training white), reached with ``adaptation``.
    adaptation : {"CAT02", "Bradford"}
    spectra : str, optional
        The chart's spectral data: with ``model="auto"``, the spectral route is scored too.
    test_patches : path or PatchSet, optional
        Independent patches, same encoding and white as the training ones.
    camera : str, optional
        The camera name recorded in the file.
    for_illuminant, sensitivities, training_reflectances, validation_reflectances, plausible_cameras
        The fit for another light (see ``camcal colour fit --help``).
    out : path, optional
        The ``*.colour.json`` to write (with ``report``, together: all or none).
    report : path, optional
        A folder for per-patch tables and plots.
    log : callable, optional
        Receives the lines the command prints while it reads the chart, e.g. ``print``.

    Returns
    -------
    ColourFit

    Raises
    ------
    CamcalError
        Bad input (one line naming it); nothing is written then.
    """
    from camcal.colour.chart.patches import PatchSet
    from camcal.io.patches import read_patch_csv
    from camcal.io.raw import is_raw

    say = log or (lambda line: None)
    if (patches is None) == (chart is None):
        raise CamcalError("give patches or a chart (one of them)")
    found = None
    if chart is not None:
        from camcal.pipelines.colour import patches_from_chart

        grid = _parse_corners(corners) if isinstance(corners, str) else corners
        found = patches_from_chart(chart, reference, corners=grid, keep_clipped=keep_clipped,
                                   illuminant=illuminant, detector=detector)
        train = found.patches
        clipped = "saturated" if is_raw(chart) else "clipped"
        excluded = f" (dropped {clipped}: {', '.join(found.excluded)})" if found.excluded else ""
        say(f"chart found by {found.detection.method}: {len(train)} / {len(found.reference.patch_names)} patches "
            f"used{excluded}")
        if found.too_dark:
            say(f"too dark: {len(found.too_dark)} patch(es) measured and weighted down by their signal-to-noise "
                f"ratio (kept): {', '.join(found.too_dark)}")
        noisy = [n for n, flag in zip(found.reference.patch_names, found.samples.noisy) if flag]
        if noisy:
            say(f"flagged noisy (kept): {', '.join(noisy)}")
        linearise = linearise or ("none" if for_illuminant or is_raw(chart) else "lut1d")
    else:
        if corners:
            raise CamcalError("--corners applies to --chart only")
        if detector != "auto":
            raise CamcalError("--detector applies to --chart only")
        train = patches if isinstance(patches, PatchSet) else read_patch_csv(patches)
        if not isinstance(patches, PatchSet):
            say(f"read {len(train)} patches from {patches}")
        linearise = linearise or "none"
    source = None if chart is None and isinstance(patches, PatchSet) else os.fspath(chart or patches)
    reference_name = None if found is None else found.reference.name
    if for_illuminant:
        fitted = _for_illuminant(train, reference_name, linearise, source, illuminant, for_illuminant, sensitivities,
                                 test_patches, target_white, model, training_reflectances, validation_reflectances,
                                 plausible_cameras, camera)
    else:
        from camcal.colour.fit.characterise import characterise

        if sensitivities:
            raise CamcalError("--sensitivities is used with --for-illuminant B")
        test = (test_patches if isinstance(test_patches, PatchSet) or test_patches is None
                else read_patch_csv(test_patches))
        fitted = characterise(train, white=illuminant, model=model, objective=objective,
                              regularisation=regularisation, linearise=linearise, test=test,
                              target_white=target_white, adaptation=adaptation, camera=camera,
                              reference=reference_name, source=source, spectra=spectra)
    fit = _with_capture(chart, fitted.fit)
    files = _write(fit, fitted, None if for_illuminant else report, camera, out)
    return ColourFit(fit, fitted, len(train), found, for_illuminant,
                     validation_reflectances if for_illuminant else None, files)


def _for_illuminant(train, reference, linearise, source, illuminant, for_illuminant, sensitivities, test_patches,
                    target_white, model, training_reflectances, validation_reflectances, plausible_cameras, camera):
    """The fit for light ``for_illuminant`` (:func:`camcal.colour.fit.illuminant.characterise_for_illuminant`)."""
    from camcal.colour.fit.illuminant import characterise_for_illuminant
    from camcal.io.ssf import load_sensitivities

    if not sensitivities:
        raise CamcalError("--for-illuminant needs --sensitivities SSF (from 'camcal colour sensitivities')")
    if linearise != "none":
        raise CamcalError(f"--for-illuminant needs linear camera RGB (--linearise none, raw input), got {linearise!r}")
    if test_patches or target_white:
        raise CamcalError("--for-illuminant judges on validation reflectances under B: drop --test-patches / "
                          "--target-white")
    if plausible_cameras < 0:
        raise CamcalError(f"--plausible-cameras must be >= 0, got {plausible_cameras}")
    sens = load_sensitivities(sensitivities)
    return characterise_for_illuminant(
        train, sens, illuminant=illuminant, for_illuminant=for_illuminant, model=model,
        training_set=training_reflectances, validation_set=validation_reflectances, n_cameras=plausible_cameras,
        camera=f"{camera} ({for_illuminant})" if camera else None, reference=reference, source=source)


def _parse_corners(text: str) -> list[list[float]]:
    """``"X,Y,..."``: the 4 corners of the patch grid (8 numbers)."""
    try:
        values = [float(v) for v in text.replace(" ", ",").split(",") if v]
    except ValueError:
        raise CamcalError(f"--corners: expected 8 numbers, got {text!r}") from None
    if len(values) != 8:
        raise CamcalError(f"--corners: expected 8 numbers, got {len(values)}")
    return [values[i : i + 2] for i in range(0, 8, 2)]


def _with_capture(chart: str | os.PathLike | None, fit):
    """The fit with the raw capture's metadata when ``chart`` is a raw file."""
    import dataclasses

    from camcal.io.raw import is_raw, raw_metadata

    if chart is not None and is_raw(chart):
        fit = dataclasses.replace(fit, capture=raw_metadata(chart).to_dict())
    return fit


def _write(fit, outcome, report: str | os.PathLike | None, camera: str | None,
           out: str | os.PathLike | None) -> tuple[tuple[Path, str], ...]:
    """Write the report folder and the fit together (all or none)."""
    from camcal.base.atomic import final_path, output_folder
    from camcal.io.colourfile import save_colour_file

    with output_folder(report) as report_dir:
        reports = []
        if report_dir is not None:
            from camcal.report.characterisation import write_report

            reports = write_report(outcome, report_dir, title=camera or "")
        files = [] if out is None else [(save_colour_file(fit, out), "colour fit")]
    return tuple(files) + tuple((final_path(path, report_dir, report), "report") for path in reports)
