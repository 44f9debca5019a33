"""``camcal colour sensitivities``: camera spectral sensitivities, estimated or measured."""

from __future__ import annotations

import argparse

from camcal.base.errors import CamcalError
from camcal.cli.options import camera_label_option, handler, name_value, out_option, output_folder, report_option
from camcal.cli.summary import summary_of

__all__ = ["register"]


def register(parser: argparse.ArgumentParser) -> None:
    """The options of ``camcal colour sensitivities``."""
    parser.add_argument("--chart", nargs="+", action="extend", metavar="ILLUMINANT=IMAGE", default=[],
                        help="a linear photo of a ColorChecker 24 under ILLUMINANT (repeatable)")
    parser.add_argument("--patches", nargs="+", action="extend", metavar="ILLUMINANT=FILE.csv", default=[],
                        help="patches with reflectance spectra under ILLUMINANT (repeatable)")
    parser.add_argument("--measured", metavar="FILE.csv", help="measured sensitivities instead of an estimate")
    parser.add_argument("--chart-spectra", default="BabelColor Average", metavar="NAME",
                        help="reflectances of the chart's patches: BabelColor Average, ColorChecker N Ohta "
                             "or ISO 17321-1 (default: %(default)s)")
    parser.add_argument("--wavelengths", default="400,700,10", metavar="START,END,STEP",
                        help="estimation grid in nm (default: %(default)s)")
    camera_label_option(parser)
    parser.add_argument("--compare", metavar="SSF", help="reference curves (*.ssf.json or CSV): print the "
                                                         "relative RMS error and both mu-factors")
    out_option(parser, "CAMERA.ssf.json", "file to write (+ .ssf.csv)")
    report_option(parser, "plot with 95 %% bands (sensitivities.png)")
    handler(parser, _sensitivities, [
        "camcal colour sensitivities --chart D65=chart_d65.dng FL2=chart_fl2.dng --camera-name cam "
        "--out cam.ssf.json",
        "camcal colour sensitivities --measured cam_measured.csv --out cam.ssf.json",
    ])


def _sensitivities(args: argparse.Namespace) -> int:
    """Estimate a camera's spectral sensitivities from chart captures (linear images: raw or linear TIFF/EXR)
    and/or spectral patch CSVs, each under a known illuminant, with positivity, smoothness and the
    regularisation chosen by K-fold cross-validation; or read measured curves (--measured). Writes
    *.ssf.json and *.ssf.csv and prints the Vora-Trussell mu-factor and the Luther-Ives deviation.

    ILLUMINANT: a colour-science SDS_ILLUMINANTS name (D65, A, FL2, LED-B3...) or a CSV wavelength,value.
    Spectral patch CSV header: name,R,G,B,<nm>,<nm>,... (linear camera RGB then reflectance samples).
    Measured CSV: wavelength,R,G,B[,sigma_R,sigma_G,sigma_B].
    """
    import numpy as np

    from camcal.colour.spectral.captures import estimate_from_captures
    from camcal.colour.spectral.sensitivities import relative_rms_error
    from camcal.io.ssf import load_sensitivities, read_sensitivities_csv, read_spectral_patch_csv, write_sensitivities
    from camcal.pipelines.colour import capture_from_chart
    from camcal.report.colour_plots import plot_sensitivities

    try:
        start, end, step = (float(v) for v in args.wavelengths.split(","))
    except ValueError:
        raise CamcalError(f"--wavelengths: expected START,END,STEP in nm, got {args.wavelengths!r}") from None
    if not (0 < step and start + 2 * step <= end):
        raise CamcalError(f"--wavelengths: need START < END with at least 3 steps, got {args.wavelengths!r}")
    wavelengths = np.arange(start, end + step / 2, step)
    reference = load_sensitivities(args.compare) if args.compare else None
    if args.measured:
        if args.chart or args.patches:
            raise CamcalError("give --measured, or captures (--chart / --patches), not both")
        sens = read_sensitivities_csv(args.measured, args.camera)
    else:
        captures = []
        for entry in args.chart:
            illuminant, path = name_value(entry, "--chart", "ILLUMINANT=IMAGE")
            captures.append(capture_from_chart(path, illuminant, wavelengths, reflectances=args.chart_spectra))
        for entry in args.patches:
            illuminant, path = name_value(entry, "--patches", "ILLUMINANT=FILE.csv")
            captures.append(read_spectral_patch_csv(path, illuminant, wavelengths))
        if not captures:
            raise CamcalError("nothing to estimate from: give --chart ILLUMINANT=IMAGE, --patches "
                              "ILLUMINANT=FILE.csv or --measured FILE.csv")
        for cap in captures:
            print(f"{cap.source}: {len(cap.names)} patches under {cap.illuminant_name}")
        sens = estimate_from_captures(captures, wavelengths, camera=args.camera)
    print(sens.summary())
    out = summary_of(args)
    out.figures(source=sens.source, wavelengths_nm=[float(sens.wavelengths[0]), float(sens.wavelengths[-1]),
                                                    float(sens.wavelengths[1] - sens.wavelengths[0])],
                **sens.quality(), estimation=sens.estimation)
    if reference is not None:
        per_channel, overall = relative_rms_error(sens.values, reference.resampled(sens.wavelengths).values)
        print(f"vs {args.compare}: relative RMS error R {100 * per_channel[0]:.1f} %, G {100 * per_channel[1]:.1f} %, "
              f"B {100 * per_channel[2]:.1f} % (overall {100 * overall:.1f} %); mu-factor {sens.mu_factor():.4f} "
              f"vs {reference.mu_factor():.4f}")
        out.figures(compare={"reference": args.compare, "relative_rms_error": [float(v) for v in per_channel],
                             "relative_rms_error_overall": overall, "mu_factor": reference.mu_factor()})
    with output_folder(args.report) as report_dir:
        if report_dir is not None:
            plot_sensitivities(report_dir / "sensitivities.png", sens, reference, title=args.camera or "")
        json_path, csv_path = write_sensitivities(args.out, sens)
    out.wrote(json_path, "sensitivities")
    out.wrote(csv_path, "sensitivities csv")
    if args.report:
        from pathlib import Path

        path = Path(args.report) / "sensitivities.png"
        out.wrote(path, "report", say=False)
        print(f"report: {path}")
    return 0
