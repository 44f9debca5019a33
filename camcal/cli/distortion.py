"""``camcal distortion fit``: a lens model from straight lines (plumb-line fit)."""

from __future__ import annotations

import argparse

from camcal.base.errors import CamcalError
from camcal.cli.options import (deprecated_option, every_option, handler, images_option, only_with, out_option,
                                output_folder, report_option, verb_group)
from camcal.cli.summary import summary_of

__all__ = ["register"]


def register(parser: argparse.ArgumentParser) -> None:
    """``fit`` under ``camcal distortion``."""
    verbs = verb_group(parser, "distortion_verb")
    fit = verbs.add_parser("fit", help="plumb-line fit (Strand & Hayman, refined by Devernay & Faugeras)")
    images_option(fit, "FILE|VIDEO", "images of one camera (repeatable), or its videos", required=False)
    every_option(fit)
    fit.add_argument("--lines", metavar="LINES.json", help="line points instead of images")
    fit.add_argument("--board", dest="pattern", type=_chessboard, metavar="chessboard:COLSxROWS",
                     help="lines through a chessboard's inner corners, e.g. chessboard:9x6 (a square size after it, "
                     "as in calibrate board, is ignored; default: long straight edges in the images)")
    deprecated_option(fit, "--pattern", "--board chessboard:COLSxROWS", dest="pattern", metavar="COLSxROWS")
    only_with(fit, "--board", "images (--images)", lambda args: bool(args.images))
    fit.add_argument("--model", choices=("division", "polynomial"), default="division",
                     help="the lens model fitted: division (one parameter) or polynomial (default: %(default)s)")
    fit.add_argument("--fit-centre", action="store_true", help="fit the distortion centre too (default: the image "
                     "centre)")
    out_option(fit, "lens.json", "the lens file to write (the fitted distortion and its straightness figures)")
    report_option(fit, "write per-line figures to DIR/plumbline_report.json")
    handler(fit, _fit, [
        "camcal distortion fit --images 'shots/left*.png' --board chessboard:9x6 --fit-centre --out left.lens.json",
        "camcal distortion fit --lines lines.json --model polynomial --out lens.json",
    ])


def _chessboard(spec: str) -> str:
    """``--board chessboard:COLSxROWS[:SQUARE...]`` as ``COLSxROWS`` (straight lines need no square size)."""
    kind, _, rest = spec.partition(":")
    if kind != "chessboard" or not rest:
        raise argparse.ArgumentTypeError(f"expected chessboard:COLSxROWS (inner corners, e.g. chessboard:9x6), "
                                         f"got {spec!r}")
    return rest.split(":")[0]


def _pattern(value: str) -> tuple[int, int]:
    try:
        cols, rows = (int(v) for v in value.lower().split("x"))
    except ValueError:
        raise CamcalError(f"--board must look like chessboard:9x6 (inner corners), got {value!r}") from None
    if cols < 2 or rows < 2:
        raise CamcalError(f"--board needs at least 2x2 inner corners, got {value!r}")
    return cols, rows


def _fit(args: argparse.Namespace) -> int:
    """Fit a division or polynomial lens model so that straight lines become straight. Lines come from chessboard
    rows/columns (--board), from long edges in the --images, or from LINES.json: {"image_size": [W, H], "lines":
    [[[x, y], ...], ...]}. A video in --images is streamed, one frame at a time (--every N: frames 0, N, 2N...).
    """
    import cv2

    from pathlib import Path

    from camcal.geometry.board import video_frame_label
    from camcal.geometry.lines import lines_from_images
    from camcal.io.video import is_video, iter_frames
    from camcal.geometry.plumbline import fit_plumbline
    from camcal.io.lines import read_lines
    from camcal.io.frames import imread
    from camcal.base.globs import file_or_glob
    from camcal.base.jsonfile import write_json

    if bool(args.images) == bool(args.lines):
        raise CamcalError("give either --images or --lines LINES.json (not both)")
    if args.lines:
        lines = read_lines(args.lines)
        skipped: list[str] = []
    else:
        if args.every < 1:
            raise CamcalError(f"--every must be 1 or more, got {args.every}")
        names: list[str] = []  # each image's name, as it is read (a video's frames are streamed)

        paths = [path for entry in args.images for path in file_or_glob("--images", entry)]

        def frames():
            for path in paths:
                if is_video(path):
                    for k, image in iter_frames(path, every=args.every):
                        names.append(video_frame_label(path, k))
                        yield image
                else:
                    names.append(path)
                    yield imread(path, cv2.IMREAD_GRAYSCALE)

        pattern = _pattern(args.pattern) if args.pattern else None
        lines, skipped_index = lines_from_images(frames(), pattern)
        skipped = [names[i] for i in skipped_index]
        what = "board" if pattern else "long straight edges"
        print(f"{what} found in {len(names) - len(skipped)} / {len(names)} images"
              + (f" (skipped: {', '.join(skipped)})" if skipped else ""))
    result = fit_plumbline(lines, args.model, fit_center=args.fit_centre)
    with output_folder(args.report) as report_dir:
        if report_dir is not None:
            write_json(report_dir / "plumbline_report.json", {
                **result.to_dict(),
                "strand_hayman": {
                    "distortion": result.initial.distortion.to_dict(),
                    "lambda_per_line": result.initial.lambda_per_line.tolist(),
                    "weights": result.initial.weights.tolist(),
                },
                "rms_before_px": result.rms_before_px.tolist(),
                "rms_after_px": result.rms_after_px.tolist(),
            })
        write_json(args.out, result.to_dict())
    params = ", ".join(f"{k} {v:.6g}" for k, v in result.distortion.params.items())
    centre = result.distortion.center or tuple(result.K[:2, 2])
    print(f"{result.distortion.model}: {params} about ({centre[0]:.2f}, {centre[1]:.2f}) px")
    out = summary_of(args)
    out.figures(distortion=result.distortion.to_dict(), straightness_rms_before_px=result.straightness_rms_before_px,
                straightness_rms_px=result.straightness_rms_px, worst_line_rms_px=float(result.rms_after_px.max()),
                n_lines=result.n_lines, n_points=result.n_points, skipped=skipped)
    out.wrote(args.out, "lens", say=False)
    if args.report:
        out.wrote(Path(args.report) / "plumbline_report.json", "report", say=False)
    print(f"straightness RMS: {result.straightness_rms_before_px:.3f} px before, "
          f"{result.straightness_rms_px:.3f} px after (worst line {result.rms_after_px.max():.3f} px, "
          f"{result.n_lines} lines, {result.n_points} points)")
    return 0
