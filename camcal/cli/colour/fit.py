"""``camcal colour fit``: a characterisation (camera RGB to XYZ) from a chart photo or a patch CSV."""

from __future__ import annotations

import argparse

from camcal.cli.options import adaptation_option, camera_label_option, handler, out_option, report_option
from camcal.cli.summary import summary_of

__all__ = ["register"]


def register(parser: argparse.ArgumentParser) -> None:
    """The options of ``camcal colour fit``."""
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--chart", metavar="IMAGE", help="photo of a colour chart (PNG/TIFF/JPEG/EXR, or raw: DNG, "
                                                          "CR2, NEF, ARW... read as linear camera RGB), in perspective, "
                                                          "turned or mirrored")
    source.add_argument("--patches", metavar="FILE.csv", help="training patches (see below)")
    parser.add_argument("--reference", default=None, metavar="NAME|FILE",
                        help="reference data for --chart: colour-science name (or cc24, cc24-2005, babel, sg) or the "
                             "chart's CGATS file (an IT8.7/2's is needed); default: the chart type's own, X-Rite's "
                             "ColorChecker24 - After November 2014 or ColorCheckerSG - After November 2014")
    parser.add_argument("--chart-type", default="auto",
                        choices=("auto", "classic", "passport", "mini", "nano", "digital-sg", "it8"),
                        help="the chart in --chart: auto finds a Digital SG or a 24-patch ColorChecker (Classic, "
                             "Passport, Mini and Nano look alike), or the chart of a --reference CGATS file "
                             "(default: %(default)s)")
    parser.add_argument("--corners", metavar="X,Y,...",
                        help="manual chart corners instead of detection: 8 numbers, top-left (dark "
                             "skin, A1), top-right, bottom-right, bottom-left of the patch grid (an IT8.7/2's: "
                             "rows A-L, its grey scale below)")
    parser.add_argument("--detector", choices=("auto", "segmentation", "cv2.mcc"), default="auto",
                        help="chart detection without --corners: camcal's segmentation, OpenCV's cv2.mcc (24-patch "
                             "charts), or auto (segmentation, then cv2.mcc); both on a normalised sRGB view of a raw "
                             "file (default: %(default)s)")
    parser.add_argument("--keep-clipped", action="store_true", help="keep patches flagged clipped")
    parser.add_argument("--flat-field", metavar="FLAT.json",
                        help="divide the chart photo by this flat field (colour flatfield) before sampling; the photo "
                             "must be raw or linear (--linearise none)")
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
        "# an IT8.7/2 with the reference file of its batch",
        "camcal colour fit --chart it8.dng --chart-type it8 --reference R190808.txt --out cam.colour.json",
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


def _fit(args: argparse.Namespace) -> int:
    """Fit camera RGB to CIE XYZ (perfect white Y = 1) and judge it by CIEDE2000 on the training patches, by
    leave-one-out and on an independent patch set. Writes a versioned *.colour.json.

    Patch CSV header: R,G,B,X,Y,Z (camera RGB, reference XYZ under the scene illuminant, perfect white Y =
    1), optional first column name. --model auto picks model, objective and regularisation by leave-one-out
    CIEDE2000 and says why.
    """
    from camcal.api.colour import fit_colour

    result = fit_colour(
        args.patches, chart=args.chart, reference=args.reference, chart_type=args.chart_type, corners=args.corners,
        detector=args.detector,
        keep_clipped=args.keep_clipped, model=args.model, objective=args.objective,
        regularisation=args.regularisation, linearise=args.linearise, illuminant=args.illuminant,
        target_white=args.target_white, adaptation=args.adaptation, spectra=args.spectra,
        test_patches=args.test_patches, camera=args.camera, for_illuminant=args.for_illuminant,
        sensitivities=args.sensitivities, training_reflectances=args.training_reflectances,
        validation_reflectances=args.validation_reflectances, plausible_cameras=args.plausible_cameras,
        flat_field=args.flat_field, out=args.out, report=args.report, log=print)
    for line in result.lines():
        print(line)
    out = summary_of(args)
    out.figures(**result.figures())
    out.wrote(next(path for path, kind in result.files if kind == "colour fit"), "colour fit")
    reports = [path for path, kind in result.files if kind == "report"]
    if reports:
        out.report(reports, args.report)
    return 0
