"""``camcal.fit_colour`` and ``camcal.export_colour``: ``colour fit`` and ``colour export``.

``fit_colour``: camera RGB to CIE XYZ from a chart photo or patches;
``export_colour``: fits as OCIO colour spaces (config + CLF) and ICC camera
profiles. (:mod:`camcal.colour` is the pure maths they run on; this module
reads the chart, the patch or fit files, runs the steps with the command's
defaults and checks, and writes the files.)
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
    from camcal.colour.export.icc import ICCProfile
    from camcal.colour.fit.characterise import Characterisation
    from camcal.io.aces import ACESExport
    from camcal.io.ocio import OCIOExport
    from camcal.pipelines.colour import ChartPatches

__all__ = ["ColourExport", "ColourFit", "export_colour", "fit_colour"]

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
    reference: str | os.PathLike | None = None,
    chart_type: str = "auto",
    corners: Sequence[Sequence[float]] | str | None = None,
    detector: str = "auto",
    keep_clipped: bool = False,
    model: str = "auto",
    objective: str | None = None,
    regularisation: float = 0.0,
    linearise: str | None = None,
    illuminant: str = "D50",
    target_white: str | None = None,
    adaptation: str = "Bradford",
    spectra: str | None = None,
    test_patches: str | os.PathLike | PatchSet | None = None,
    camera: str | None = None,
    for_illuminant: str | None = None,
    sensitivities: str | os.PathLike | None = None,
    training_reflectances: str = "rawtoaces 190",
    validation_reflectances: str = "Munsell validation",
    plausible_cameras: int = 0,
    flat_field: str | os.PathLike | None = None,
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
        A photo of a chart (PNG / TIFF / JPEG / EXR, or raw: DNG, CR2, NEF, ARW..., read as linear camera RGB):
        a ColorChecker Classic, Passport, Mini or Nano, a Digital SG or an IT8.7/2, in perspective, turned or
        mirrored.
    reference : str or path, optional
        The chart's reference data: a colour-science name (or cc24, cc24-2005, babel, sg), the chart's CGATS file
        (an IT8.7/2's is needed), or None for the chart type's own (X-Rite's values).
    chart_type : str
        ``auto`` (the Digital SG or the 24-patch ColorChecker, found in the photo; an IT8.7/2 by its CGATS file)
        or ``classic``, ``passport``, ``mini``, ``nano``, ``digital-sg``, ``it8``.
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
    adaptation : {"Bradford", "CAT02"}
        The chromatic adaptation to ``target_white`` (Bradford, the command line's and the OCIO export's).
    spectra : str, optional
        The chart's spectral data: with ``model="auto"``, the spectral route is scored too.
    test_patches : path or PatchSet, optional
        Independent patches, same encoding and white as the training ones.
    camera : str, optional
        The camera name recorded in the file.
    for_illuminant, sensitivities, training_reflectances, validation_reflectances, plausible_cameras
        The fit for another light (see ``camcal colour fit --help``).
    flat_field : path, optional
        A flat field (``colour flatfield``'s JSON) the chart photo is divided by before sampling; the photo must
        be linear (raw, or with ``linearise="none"``).
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
        flat = None
        if flat_field is not None:
            from camcal.io.flatfield import load_flat_field

            if not is_raw(chart) and linearise != "none":
                raise CamcalError("--flat-field divides linear values: the chart must be a raw file, or linear "
                                  "with --linearise none")
            flat = load_flat_field(flat_field)
        found = patches_from_chart(chart, reference, corners=grid, keep_clipped=keep_clipped,
                                   illuminant=illuminant, detector=detector, flat_field=flat, chart_type=chart_type)
        train = found.patches
        clipped = "saturated" if is_raw(chart) else "clipped"
        excluded = f" (dropped {clipped}: {', '.join(found.excluded)})" if found.excluded else ""
        say(f"chart found by {found.detection.method}: {len(train)} / {len(found.reference.patch_names)} patches "
            f"used{excluded}")
        say(_chart_line(found, chart_type))
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
        if flat_field is not None:
            raise CamcalError("--flat-field applies to --chart only")
        if detector != "auto":
            raise CamcalError("--detector applies to --chart only")
        if chart_type != "auto":
            raise CamcalError("--chart-type applies to --chart only")
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


def _chart_line(found: ChartPatches, chart_type: str) -> str:
    """What chart was found and how it was seen: its type, and whether mirrored."""
    from camcal.colour.chart.layouts import chart_layout

    layout = chart_layout(found.reference.layout or "classic")
    title = ("ColorChecker 24 (Classic, Passport, Mini or Nano look alike)"
             if layout.family == "24" and chart_type == "auto" else layout.title)
    seen = "seen mirrored, patches in chart order" if found.detection.mirrored else "seen from its front"
    return f"chart type: {title}, reference {found.reference.name}; {seen}"


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


@dataclass(frozen=True)
class ColourExport:
    """What :func:`export_colour` wrote.

    Attributes
    ----------
    ocio : OCIOExport or None
        With ``ocio``: the config written (``config_path`` in its final folder), the base it extends (a built-in
        alias resolved), its OCIO profile version and each camera space (model, kind, LUT size, CLF, bake error).
    icc : ICCProfile or None
        With ``icc``: the profile written (version, kind, CLUT sizes and bake errors).
    icc_path : Path or None
        Where the ICC profile was written.
    n_spaces, n_matches : int
        Camera spaces (one per characterisation) and match Looks (one per camera match) in the config.
    files : tuple of (Path, str)
        ``(path, kind)`` of the files written: ``ocio config``, each ``clf``, ``icc``, then the ACES hand-off's
        ``aces clf``, ``amf``, ``dctl``.
    aces : ACESExport or None
        With ``clf``, ``amf`` or ``dctl``: the camera's ACES input transform (its transform ID, model, bake error)
        and the files written.
    """

    ocio: OCIOExport | None
    icc: ICCProfile | None
    icc_path: Path | None
    n_spaces: int
    n_matches: int
    files: tuple[tuple[Path, str], ...] = ()
    aces: ACESExport | None = None

    def lines(self) -> list[str]:
        """The lines ``colour export`` prints: each space, the config written, the ICC profile written."""
        lines = []
        if self.ocio is not None:
            lines += [space.summary() for space in self.ocio.spaces]
            lines.append(f"wrote {self.ocio.config_path} (OCIO profile {self.ocio.profile_version}, base "
                         f"{self.ocio.base}, {self.n_spaces} camera space(s), {self.n_matches} match Look(s))")
        if self.icc is not None:
            lines.append(f"wrote {self.icc_path} (ICC v{self.icc.version}, {self.icc.summary()})")
        if self.aces is not None:
            lines += self.aces.lines()
        return lines

    def figures(self) -> dict[str, Any]:
        """The figures of ``colour export --json``."""
        import dataclasses

        def stats(value):
            return None if value is None else dataclasses.asdict(value)

        figures: dict[str, Any] = {}
        if self.ocio is not None:
            figures.update(base=self.ocio.base, ocio_profile_version=self.ocio.profile_version,
                           n_matches=self.n_matches, spaces=[{
                               "name": space.name, "camera": space.camera, "model": space.model,
                               "kind": space.kind, "lut_size": space.lut_size, "clf": space.clf,
                               "linearisation_error": space.linearisation_error,
                               "bake_error_delta_E2000": stats(space.bake_error),
                           } for space in self.ocio.spaces])
        if self.icc is not None:
            icc = self.icc
            figures.update(icc={"version": icc.version, "kind": icc.kind, "bake_error_delta_E2000":
                                None if icc.kind == "matrix-trc" else stats(icc.bake_error),
                                "float_clut_size": icc.float_clut_size,
                                "float_bake_error_delta_E2000": stats(icc.float_bake_error)})
        if self.aces is not None:
            transform = self.aces.transform
            figures.update(aces={"transform_id": transform.transform_id, "user_name": transform.user_name,
                                 "space": transform.space, "kind": transform.kind,
                                 "lut_size": None if transform.baked is None else transform.baked.lut_size,
                                 "bake_error_delta_E2000": stats(transform.bake_error),
                                 "linearisation_error": transform.linearisation_error,
                                 "amf_applied": self.aces.applied if self.aces.amf is not None else None})
        return figures


def export_colour(
    fits: Sequence[str | os.PathLike],
    *,
    ocio: str | os.PathLike | None = None,
    icc: str | os.PathLike | None = None,
    camera: str | None = None,
    by_illuminant: bool = False,
    base: str = "ocio://studio-config-latest",
    ocio_version: str | None = None,
    family: str | None = None,
    adaptation: str = "Bradford",
    icc_version: int = 4,
    max_bake_error: float = 0.2,
    clf: str | os.PathLike | None = None,
    amf: str | os.PathLike | None = None,
    dctl: str | os.PathLike | None = None,
    aces_space: str = "ACES2065-1",
    applied: bool = False,
) -> ColourExport:
    """Export characterisations (``*.colour.json``) as OCIO input colour spaces, an ICC camera profile and/or the
    camera's ACES input transform as CLF, AMF and DCTL (``camcal colour export``).

    Each fit becomes the space ``camcal <camera>`` (family ``Input/<maker>`` of a raw capture, else
    ``Input/camcal``) of an OpenColorIO config; a camera match becomes a Look. Matrix fits are exact; other models
    are baked (log-chromaticity shaper + 3D LUT; ICC v4: float D2B0/D2B1 plus a 16-bit A2B0) with the bake error
    checked, in CIEDE2000 (Sharma et al. 2005), over the chart gamut and plausible surface colours.

    Parameters
    ----------
    fits : sequence of path
        ``*.colour.json`` files (characterisations, and camera matches for the config); with ``by_illuminant``
        an entry ``"LIGHT=FIT.colour.json"`` names the light.
    ocio : path, optional
        The folder of ``config.ocio`` and ``luts/*.clf`` (written together: all or none). A studio's config given
        as ``base`` in this folder is extended in place.
    icc : path, optional
        The ICC camera profile to write (one fit only).
    camera : str, optional
        The camera name (one fit, or with ``by_illuminant``); default: the fit's camera, else the file name.
    by_illuminant : bool
        One space per fit, ``camcal <camera> (<light>)``: a camera's fits for several lights in one config.
    base : str
        The config the spaces are added to: ``"camcal"``, an ``ocio://`` built-in or a ``.ocio`` file with an
        ``aces_interchange`` role.
    ocio_version : str, optional
        The OCIO profile version written, the oldest OpenColorIO that must load the config (2.1 to 2.6; default
        2.3, :data:`camcal.colour.export.ocio_versions.DEFAULT_PROFILE_VERSION`, as the command's).
    family : str, optional
        The family of the camera spaces (default: ``Input/<maker>`` of a raw capture, else ``Input/camcal``).
    adaptation : {"Bradford", "CAT02"}
        The chromatic adaptation from the fit's white to the ACES white.
    icc_version : {4, 2}
        The ICC profile version (ICC.1:2010 or ICC.1:2001-04).
    max_bake_error : float
        The largest CIEDE2000 a baked LUT may add.
    clf : path, optional
        The camera's ACES input transform as a CLF (SMPTE ST 2136-1) with its ACES transform ID and the camera,
        chart, light and fit in its ``Info`` (one fit only; :mod:`camcal.colour.export.aces`).
    amf : path, optional
        An ACES Metadata File 2.0 naming that CLF as the input transform (needs ``clf``).
    dctl : path, optional
        The same transform as a DaVinci Resolve DCTL, the curves and the model's terms inlined (matrix, polynomial
        and root-polynomial fits).
    aces_space : {"ACES2065-1", "ACEScg"}
        The space the CLF and DCTL convert to (an AMF needs ACES2065-1).
    applied : bool
        The AMF's ``applied``: the images it goes with already hold the input transform.

    Returns
    -------
    ColourExport

    Raises
    ------
    CamcalError
        Bad input (one line naming it, the command's option); nothing is written then.
    """
    import dataclasses

    from camcal.base.atomic import final_path, output_folder
    from camcal.colour.fit.record import ColourFit as FitRecord
    from camcal.io.colourfile import load_colour_file

    aces = clf is not None or amf is not None or dctl is not None
    if not ocio and not icc and not aces:
        raise CamcalError("nothing to write: give --ocio OUTDIR, --icc OUT.icc, --clf OUT.clf, --amf OUT.amf or "
                          "--dctl OUT.dctl")
    if camera and len(fits) > 1 and not by_illuminant:
        raise CamcalError(f"--camera-name needs exactly one fit (or --by-illuminant), got {len(fits)}")
    for option, value in (("--ocio-version", ocio_version), ("--family", family)):
        if value and not ocio:
            raise CamcalError(f"{option} applies to the OCIO config: give --ocio OUTDIR")
    if by_illuminant and not ocio:
        raise CamcalError("--by-illuminant names OCIO colour spaces: give --ocio OUTDIR")
    if icc and len(fits) > 1:
        raise CamcalError(f"--icc writes one profile: give one fit, got {len(fits)}")
    if aces and len(fits) > 1:
        raise CamcalError(f"--clf, --amf and --dctl write one camera's input transform: give one fit, got {len(fits)}")
    if (aces_space != "ACES2065-1" or applied) and not aces:
        raise CamcalError("--aces-space and --applied apply to --clf, --amf and --dctl")
    if applied and amf is None:
        raise CamcalError("--applied is the AMF's: give --amf OUT.amf")
    if not (max_bake_error > 0):
        raise CamcalError(f"--max-bake-error must be > 0, got {max_bake_error}")
    named, matches = [], []
    for entry in fits:
        path, light, text = entry, None, os.fspath(entry)
        if by_illuminant and "=" in text and not Path(entry).is_file():
            light, path = text.split("=", 1)
            if not light.strip():
                raise CamcalError(f"empty light name in {text!r} (expected LIGHT=FIT.colour.json)")
        fit = load_colour_file(path)
        if not isinstance(fit, FitRecord):
            if light is not None:
                raise CamcalError(f"{path} is a camera match, not a characterisation: it has no light to name")
            matches.append(fit)
            continue
        name = camera or fit.camera or Path(path).name.removesuffix(".json").removesuffix(".colour")
        named.append((name, fit, light))
    if by_illuminant:
        from camcal.colour.export.ocio_fit import names_by_illuminant

        spaces = names_by_illuminant(named)
    else:
        spaces = [(name, fit) for name, fit, _ in named]
    if icc and not spaces:
        raise CamcalError("--icc needs a characterisation (kind characterisation); a camera match has no ICC profile")
    if aces and not spaces:
        raise CamcalError("--clf, --amf and --dctl need a characterisation (kind characterisation); a camera match "
                          "has no input transform")
    handoff = None
    if aces:
        from camcal.io.aces import build_aces

        handoff = build_aces(spaces[0][1], spaces[0][0], clf=clf, amf=amf, dctl=dctl, space=aces_space,
                              cat=adaptation, max_delta_E=max_bake_error, applied=applied)
    profile = None
    if icc:
        from camcal.colour.export.icc import icc_profile_from_fit

        profile = icc_profile_from_fit(spaces[0][1], spaces[0][0], version=icc_version, max_delta_E=max_bake_error)
    exported, files = None, []
    if ocio:
        from camcal.io.ocio import export_ocio

        version = {"ocio_version": ocio_version} if ocio_version else {}
        with output_folder(ocio) as ocio_dir:
            exported = export_ocio(spaces, ocio_dir, base=base, cat=adaptation, max_delta_E=max_bake_error,
                                   matches=matches, family=family, home=ocio, **version)
        exported = dataclasses.replace(exported, config_path=final_path(exported.config_path, ocio_dir, ocio))
        files.append((exported.config_path, "ocio config"))
        files += [(Path(ocio) / space.clf, "clf") for space in exported.spaces if space.clf]
    icc_path = None
    if profile is not None:
        from camcal.io.icc import write_icc

        icc_path = write_icc(profile, icc)
        files.append((icc_path, "icc"))
    if handoff is not None:
        handoff.write()
        files += [(path, kind) for path, kind in ((handoff.clf, "aces clf"), (handoff.amf, "amf"),
                                                  (handoff.dctl, "dctl")) if path is not None]
    return ColourExport(exported, profile, icc_path, len(spaces), len(matches), tuple(files), handoff)
