"""``camcal colour fit``: a characterisation (camera RGB to XYZ) from a chart photo or a patch CSV."""

from __future__ import annotations

import argparse

from camcal.base.errors import CamcalError
from camcal.cli.options import (adaptation_option, camera_label_option, handler, out_option, output_folder,
                                report_option)
from camcal.cli.summary import summary_of

__all__ = ["register"]


def register(parser: argparse.ArgumentParser) -> None:
    """The options of ``camcal colour fit``."""
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--chart", metavar="IMAGE", help="photo of a 24-patch ColorChecker (PNG/TIFF/JPEG/EXR, or "
                                                          "raw: DNG, CR2, NEF, ARW... read as linear camera RGB)")
    source.add_argument("--patches", metavar="FILE.csv", help="training patches (see below)")
    parser.add_argument("--reference", default="ColorChecker24 - After November 2014", metavar="NAME",
                        help="reference chart for --chart (colour-science name or cc24, cc24-2005, "
                             "babel, sg; default: %(default)s)")
    parser.add_argument("--corners", metavar="X,Y,...",
                        help="manual chart corners instead of detection: 8 numbers, top-left (dark "
                             "skin), top-right, bottom-right, bottom-left of the patch grid")
    parser.add_argument("--detector", choices=("auto", "segmentation", "cv2.mcc"), default="auto",
                        help="chart detection without --corners: camcal's segmentation, OpenCV's cv2.mcc, or auto "
                             "(segmentation, then cv2.mcc); both on a normalised sRGB view of a raw file (default: %(default)s)")
    parser.add_argument("--keep-clipped", action="store_true", help="keep patches flagged clipped")
    parser.add_argument("--model", default="auto",
                        help="auto | matrix3x3[:white-preserving] | polynomial:N | root-polynomial:D "
                             "| rbf[:KERNEL] (default: auto)")
    parser.add_argument("--objective", choices=("xyz", "de2000"), default=None,
                        help="least squares in XYZ or CIEDE2000 (default: xyz; auto tries both)")
    parser.add_argument("--regularisation", type=float, default=0.0, metavar="LAMBDA",
                        help="ridge lambda on the non-linear terms of a named model (auto picks its own; default: "
                             "%(default)s)")
    parser.add_argument("--linearise", default=None, metavar="KIND",
                        help="none | gamma-offset | lut1d | named:FUNCTION (e.g. named:sRGB); "
                             "default: lut1d for --chart, none for --patches")
    parser.add_argument("--illuminant", default="D50", metavar="WHITE",
                        help="white the reference XYZ are relative to: CIE name or x,y "
                             "(default: D50, the ColorChecker data's own; with --chart, another "
                             "white adapts the chart's data to it with CAT02)")
    parser.add_argument("--target-white", default=None, metavar="WHITE",
                        help="white of the output XYZ (default: the training white)")
    adaptation_option(parser, "to the --target-white", "--target-white", lambda args: args.target_white is not None)
    parser.add_argument("--spectra", default=None, metavar="NAME",
                        help="the chart's spectral data (BabelColor Average, ColorChecker N Ohta, ISO 17321-1), "
                             "patch names matching: with --model auto, sensitivities are estimated from the chart, "
                             "candidates scored on 300 Munsell colours rendered through them and also trained on "
                             "the 99 CIE 2017 samples and 300 other Munsell colours beside the chart (the spectral "
                             "route, each model with the ridge the held-out colours prefer); the chart-only and "
                             "spectral picks "
                             "are compared on the chart's patches held out and the better one written")
    parser.add_argument("--test-patches", metavar="FILE.csv",
                        help="independent patches, same encoding and white as the training ones")
    camera_label_option(parser)
    out_option(parser, "FIT.colour.json", "fit file to write")
    report_option(parser, "write per-patch tables and plots here")
    _register_for_illuminant(parser)
    handler(parser, _fit, [
        "camcal colour fit --chart chart.png --illuminant D65 --camera-name left --out "
        "left.colour.json --report colour_report",
        "camcal colour fit --patches patches.csv --model root-polynomial:2 --target-white D65 "
        "--adaptation CAT02 --out cam.colour.json",
        "# a fit for tungsten light from a chart shot under D65 and the camera's sensitivities",
        "camcal colour fit --chart chart_d65.dng --illuminant D65 --for-illuminant A --sensitivities "
        "cam.ssf.json --out cam_a.colour.json",
    ])


def _register_for_illuminant(parser) -> None:
    """``colour fit --for-illuminant B --sensitivities SSF``: a fit for another light."""
    group = parser.add_argument_group(
        "another illuminant",
        "fit for the light B the camera will be used under, from a chart shot under --illuminant A: the "
        "spectral route (ACES P-2013-001: training reflectances through the sensitivities under B) vs the "
        "chart fit white-balanced and adapted with CAT02 / Bradford, each with each model under --model auto; the "
        "pair with the lowest RMS CIEDE2000 on validation "
        "reflectances is written (its camera name gets ' (B)', so one OCIO input space per illuminant). "
        "The chart RGB must be linear (raw or --linearise none).")
    group.add_argument("--for-illuminant", metavar="B", help="CIE illuminant name the fit is for (A, D50, FL2...)")
    group.add_argument("--sensitivities", metavar="SSF", help="*.ssf.json or measured CSV (colour sensitivities)")
    group.add_argument("--training-reflectances", default="rawtoaces 190", metavar="SET",
                       help="spectral route training set (default: %(default)s)")
    group.add_argument("--validation-reflectances", default="Munsell validation", metavar="SET",
                       help="reflectances the routes are compared on (default: %(default)s)")
    group.add_argument("--plausible-cameras", type=int, default=0, metavar="N",
                       help="compare over N cameras drawn from the sensitivities' uncertainty (default: 0, "
                            "the curves themselves)")


def _parse_corners(text: str):
    try:
        values = [float(v) for v in text.replace(" ", ",").split(",") if v]
    except ValueError:
        raise CamcalError(f"--corners: expected 8 numbers, got {text!r}") from None
    if len(values) != 8:
        raise CamcalError(f"--corners: expected 8 numbers, got {len(values)}")
    return [values[i : i + 2] for i in range(0, 8, 2)]


def _fit(args: argparse.Namespace) -> int:
    """Fit camera RGB to CIE XYZ (perfect white Y = 1) and judge it by CIEDE2000 on the training patches, by
    leave-one-out and on an independent patch set. Writes a versioned *.colour.json.

    Patch CSV header: R,G,B,X,Y,Z (camera RGB, reference XYZ under the scene illuminant, perfect white Y =
    1), optional first column name. --model auto picks model, objective and regularisation by leave-one-out
    CIEDE2000 and says why.
    """
    import dataclasses

    from camcal.colour.fit.characterise import characterise
    from camcal.io.colourfile import save_colour_file
    from camcal.io.patches import read_patch_csv
    from camcal.pipelines.colour import patches_from_chart
    from camcal.io.raw import is_raw
    from camcal.base.atomic import final_path
    from camcal.report.characterisation import write_report

    reference = None
    if args.chart:
        corners = _parse_corners(args.corners) if args.corners else None
        found = patches_from_chart(args.chart, args.reference, corners=corners,
                                   keep_clipped=args.keep_clipped, illuminant=args.illuminant,
                                   detector=args.detector)
        train = found.patches
        reference = found.reference.name
        clipped = "saturated" if is_raw(args.chart) else "clipped"
        excluded = f" (dropped {clipped}: {', '.join(found.excluded)})" if found.excluded else ""
        print(f"chart found by {found.detection.method}: {len(train)} / "
              f"{len(found.reference.patch_names)} patches used{excluded}")
        if found.too_dark:
            print(f"too dark: {len(found.too_dark)} patch(es) measured and weighted down by their signal-to-noise "
                  f"ratio (kept): {', '.join(found.too_dark)}")
        noisy = [n for n, flag in zip(found.reference.patch_names, found.samples.noisy) if flag]
        if noisy:
            print(f"flagged noisy (kept): {', '.join(noisy)}")
        linearise = args.linearise or ("none" if args.for_illuminant or is_raw(args.chart) else "lut1d")
        white = args.illuminant
    else:
        if args.corners:
            raise CamcalError("--corners applies to --chart only")
        if args.detector != "auto":
            raise CamcalError("--detector applies to --chart only")
        train = read_patch_csv(args.patches)
        print(f"read {len(train)} patches from {args.patches}")
        linearise = args.linearise or "none"
        white = args.illuminant
    if args.for_illuminant:
        return _fit_for_illuminant(args, train, reference, linearise)
    if args.sensitivities:
        raise CamcalError("--sensitivities is used with --for-illuminant B")
    test = read_patch_csv(args.test_patches) if args.test_patches else None
    outcome = characterise(
        train, white=white, model=args.model, objective=args.objective,
        regularisation=args.regularisation, linearise=linearise,
        test=test, target_white=args.target_white, adaptation=args.adaptation,
        camera=args.camera, reference=reference, source=args.chart or args.patches,
        spectra=args.spectra,
    )
    print(outcome.summary())
    fit = _with_capture(args, outcome.fit)
    out = summary_of(args)
    stats = {name: None if value is None else dataclasses.asdict(value) for name, value in (
        ("train", outcome.result.stats_train), ("loo", outcome.result.stats_loo), ("test", outcome.result.stats_test))}
    out.figures(model=outcome.result.model.label, linearisation=outcome.fit.linearisation.label,
                selection=None if outcome.selection is None else outcome.selection.reason,
                n_train=len(train), delta_E2000=stats,
                **({"n_too_dark": len(found.too_dark), "n_dropped": len(found.excluded)} if args.chart else {}))
    with output_folder(args.report) as report_dir:
        reports = [] if report_dir is None else write_report(outcome, report_dir, title=args.camera or "")
        out.wrote(save_colour_file(fit, args.out), "colour fit")
    if args.report:
        out.report([final_path(path, report_dir, args.report) for path in reports], args.report)
    return 0


def _fit_for_illuminant(args: argparse.Namespace, train, reference, linearise: str) -> int:
    from camcal.colour.fit.illuminant import characterise_for_illuminant
    from camcal.io.colourfile import save_colour_file
    from camcal.io.ssf import load_sensitivities

    if not args.sensitivities:
        raise CamcalError("--for-illuminant needs --sensitivities SSF (from 'camcal colour sensitivities')")
    if linearise != "none":
        raise CamcalError(f"--for-illuminant needs linear camera RGB (--linearise none, raw input), got {linearise!r}")
    if args.test_patches or args.target_white:
        raise CamcalError("--for-illuminant judges on validation reflectances under B: drop --test-patches / --target-white")
    if args.plausible_cameras < 0:
        raise CamcalError(f"--plausible-cameras must be >= 0, got {args.plausible_cameras}")
    sens = load_sensitivities(args.sensitivities)
    camera = f"{args.camera} ({args.for_illuminant})" if args.camera else None
    outcome = characterise_for_illuminant(
        train, sens, illuminant=args.illuminant, for_illuminant=args.for_illuminant, model=args.model,
        training_set=args.training_reflectances, validation_set=args.validation_reflectances,
        n_cameras=args.plausible_cameras, camera=camera, reference=reference,
        source=args.chart or args.patches)
    print(outcome.summary())
    fit = _with_capture(args, outcome.fit)
    out = summary_of(args)
    out.figures(for_illuminant=args.for_illuminant, route=outcome.picked, model=fit.model.label,
                n_train=len(train), reason=outcome.reason, validation_reflectances=args.validation_reflectances,
                delta_E2000_validation={score.route: score.to_dict() for score in outcome.scores})
    out.wrote(save_colour_file(fit, args.out), "colour fit")
    return 0


def _with_capture(args: argparse.Namespace, fit):
    """The fit with the raw capture's metadata when ``--chart`` is a raw file."""
    import dataclasses

    from camcal.io.raw import is_raw, raw_metadata

    if args.chart and is_raw(args.chart):
        fit = dataclasses.replace(fit, capture=raw_metadata(args.chart).to_dict())
    return fit
