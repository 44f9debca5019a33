"""``camcal colour flatfield``: a lens's flat field and vignetting from grey cards or neutral patches."""

from __future__ import annotations

import argparse

from camcal.cli.options import handler, image_size, image_size_option, out_option
from camcal.cli.summary import report_result

__all__ = ["register"]


def register(parser: argparse.ArgumentParser) -> None:
    """The options of ``camcal colour flatfield``."""
    source = parser.add_mutually_exclusive_group(required=True)
    source.add_argument("--images", nargs="+", metavar="FILE|GLOB",
                        help="grey-card photos, one size, linear: raw (DNG, CR2, NEF...), EXR, 16-bit or float TIFF")
    source.add_argument("--patches", metavar="FILE.csv",
                        help="neutral patches seen at several places in the frame: CSV x,y,R,G,B,patch[,shot] "
                             "(centre in pixels, linear value, patch name, photo)")
    image_size_option(parser, "with --patches: the photos' size in pixels")
    parser.add_argument("--mask", metavar="IMAGE",
                        help="an image whose non-zero pixels are the card, for every photo (default: the fit "
                             "rejects what is not the card)")
    parser.add_argument("--linear", action="store_true",
                        help="the 8-bit images hold linear values (8-bit images are refused without it: they are "
                             "almost always display-encoded)")
    parser.add_argument("--smooth-degree", type=int, default=0, metavar="N",
                        help="degree 0 to 4 of a smooth non-radial term beside the radial falloff (default: "
                             "%(default)s, radial only; 2 also holds a wide lens's natural falloff in the corners "
                             "a card does not reach)")
    parser.add_argument("--fixed-centre", action="store_true",
                        help="keep the optical centre at the image centre (default: fitted)")
    out_option(parser, "FLAT.json", "the flat field to write (JSON: model, image size, coefficients, residual)")
    parser.add_argument("--gain-exr", metavar="GAIN.exr",
                        help="also write the gain per pixel as a float RGB EXR (divide a linear image by it)")
    lens = parser.add_argument_group(
        "Lensfun", "a Lensfun database file with the vignetting entry (model pa, one falloff for every channel) "
                   "for the lens state the grey cards were shot at")
    lens.add_argument("--lensfun", metavar="LENS.xml",
                      help="the Lensfun file to write; an existing one with one lens (rig export --to lensfun's, or "
                           "this command's for another lens state) gets the entry added, fitted about its centre")
    lens.add_argument("--focal-mm", type=float, metavar="F", help="focal length in mm")
    lens.add_argument("--aperture", type=float, metavar="N", help="f-number")
    lens.add_argument("--distance-m", type=float, metavar="D",
                      help="focus distance in metres (inf: written as 1000, as Lensfun's own calibration tool does)")
    lens.add_argument("--lens-name", default="camcal flat field", metavar="NAME",
                      help="the lens' model name (default: %(default)s)")
    lens.add_argument("--sensor-width-mm", type=float, metavar="MM",
                      help="sensor width for Lensfun's crop factor (default: 36, full frame)")
    handler(parser, _flatfield, [
        "camcal colour flatfield --images 'grey/*.exr' --out flat.json --gain-exr flat_gain.exr",
        "camcal colour flatfield --images grey.dng --out flat.json --lensfun lens.xml --focal-mm 35 "
        "--aperture 4 --distance-m 2",
        "# the chart's neutral patches photographed at several places in the frame",
        "camcal colour flatfield --patches neutrals.csv --image-size 6000 4000 --out flat.json",
        "# the card's pixels given, and a smooth term for falloff that is not radial",
        "camcal colour flatfield --images grey1.tif grey2.tif --mask card.png --smooth-degree 2 --out flat.json",
    ])


def _flatfield(args: argparse.Namespace) -> int:
    """Fit a lens's flat field: per channel, the radial falloff 1 + k1 r^2 + k2 r^4 + k3 r^6 (Lensfun's pa
    model, r = 1 at the half diagonal) about a fitted optical centre, times an optional smooth non-radial term;
    the gain is 1 at the optical centre. Prints the residual and the gain's uncertainty (from the photos' noise).

    Inputs must be linear: raw files, EXR, 16-bit or float TIFF; an 8-bit image is refused unless --linear says
    it holds linear values. Photos of one size; a card too dark (below 20 times its noise) is refused. Shoot the
    card filling the frame, evenly lit, 1 to 2 stops below clipping; several photos average out its flaws.

    Use it: 'colour fit --flat-field FLAT.json' divides the chart photo by it before sampling; the gain EXR
    divides any linear image in a compositor; the Lensfun file corrects vignetting in darktable, RawTherapee or
    Hugin.
    """
    from camcal.api.flatfield import fit_flat_field

    result = fit_flat_field(
        args.images, patches=args.patches, image_size=image_size(args.image_size) if args.image_size else None,
        mask=args.mask, linear=args.linear, smooth_degree=args.smooth_degree, fit_centre=not args.fixed_centre,
        out=args.out, gain_exr=args.gain_exr, lensfun=args.lensfun, focal_mm=args.focal_mm, aperture=args.aperture,
        distance_m=args.distance_m, lens_name=args.lens_name, sensor_width_mm=args.sensor_width_mm)
    report_result(args, result)
    return 0
