"""``camcal colour export``: fits as OCIO colour spaces (config + CLF), ICC camera profiles and the ACES hand-off
(CLF with its ACES transform ID, AMF, DCTL)."""

from __future__ import annotations

import argparse

from camcal.cli.options import adaptation_option, handler, only_with
from camcal.cli.summary import report_result

__all__ = ["register"]


def register(parser: argparse.ArgumentParser) -> None:
    """The options of ``camcal colour export``."""
    parser.add_argument("fits", nargs="+", metavar="FIT.colour.json",
                        help="characterisation files (with --by-illuminant, LIGHT=FIT.colour.json names the light)")
    parser.add_argument("--camera-name", metavar="NAME",
                        help="camera name (one fit only; default: the fit's camera, else the file name)")
    parser.add_argument("--ocio", metavar="OUTDIR", help="write OUTDIR/config.ocio and OUTDIR/luts/*.clf")
    parser.add_argument("--by-illuminant", action="store_true",
                        help="one space per fit named 'camcal <camera> (<light>)': a camera's fits for D65, A and "
                             "any measured light in one config (the light: the fit's --for-illuminant, else the "
                             "illuminant its chart was shot under, a light file's name, or LIGHT= before the fit)")
    parser.add_argument("--base", default="ocio://studio-config-latest", metavar="CONFIG",
                        help="config to add the spaces to (default: %(default)s; see below)")
    parser.add_argument("--ocio-version", metavar="X.Y",
                        help="OCIO profile version to write, the oldest OpenColorIO that must load the config: 2.1 "
                             "to 2.6 (default: 2.3, loaded by Blender 4.2 and later and the VFX Reference Platform "
                             "CY2024 and later; 2.5: Blender 5.2 and 5.3, CY2026)")
    parser.add_argument("--family", metavar="FAMILY",
                        help="family of the camera spaces, e.g. a studio's own 'Input/Witness' (default: Input/<maker> "
                             "from the raw capture, else Input/camcal)")
    parser.add_argument("--clf", metavar="OUT.clf",
                        help="write the camera's ACES input transform as a CLF (SMPTE ST 2136-1) with its ACES "
                             "transform ID and the camera, chart, light and fit in its Info (one fit only)")
    parser.add_argument("--amf", metavar="OUT.amf",
                        help="write an ACES Metadata File 2.0 whose input transform is the --clf file (named by its "
                             "path and SHA-256), so the transform is applied once")
    parser.add_argument("--applied", action="store_true",
                        help="with --amf: the images the AMF goes with already hold the input transform (e.g. "
                             "ACES2065-1 pulls); default: not applied, the AMF is the recipe")
    only_with(parser, "--applied", "--amf", lambda args: args.amf is not None)
    parser.add_argument("--dctl", metavar="OUT.dctl",
                        help="write the same transform as a DaVinci Resolve DCTL, its curves and model inlined "
                             "(matrix, polynomial and root-polynomial fits; listed as an ACES Input Transform when it "
                             "converts to ACES2065-1)")
    parser.add_argument("--aces-space", choices=("ACES2065-1", "ACEScg"), default=None,
                        help="with --clf / --dctl: the space the input transform converts to (default: ACES2065-1; "
                             "an AMF's input transform is to ACES2065-1)")
    only_with(parser, "--aces-space", "--clf or --dctl", lambda args: bool(args.clf or args.dctl),
              default="ACES2065-1")
    adaptation_option(parser, "from the fit's white to the ACES white", "--ocio, --clf or --dctl",
                      lambda args: bool(args.ocio is not None or args.clf or args.dctl), dest="cat", old="--cat")
    parser.add_argument("--icc", metavar="OUT.icc", help="write an ICC camera profile (one fit only)")
    parser.add_argument("--icc-version", type=int, choices=(4, 2), default=None,
                        help="with --icc: the ICC profile version, 4 (ICC.1:2010, default) or 2 (ICC.1:2001-04)")
    only_with(parser, "--icc-version", "--icc", lambda args: args.icc is not None, default=4)
    parser.add_argument("--max-bake-error", type=float, default=0.2, metavar="DE",
                        help="largest CIEDE2000 a baked LUT may add over the chart gamut and plausible surface "
                        "colours (default: %(default)s)")
    handler(parser, _export, [
        "camcal colour export left.colour.json right.colour.json --ocio ocio_out",
        "camcal colour export left.colour.json --icc left.icc",
        "camcal colour export cam_d65.colour.json cam_a.colour.json --by-illuminant --ocio ocio_out",
        "# the ACES hand-off: the input transform as CLF, an AMF naming it, the same transform for Resolve",
        "camcal colour export left.colour.json --clf left.clf --amf left.amf --dctl left.dctl",
    ])


def _export(args: argparse.Namespace) -> int:
    """Export characterisations (*.colour.json) as input colour spaces 'camcal <camera>' (family Input/camcal) of
    an OpenColorIO config, as an ICC camera profile and/or as the camera's ACES input transform (CLF, AMF, DCTL).
    Matrix fits are exact; other models are baked (log-chromaticity shaper + 3D LUT; ICC v4: float D2B0/D2B1
    plus a 16-bit A2B0) with the bake error checked over the chart gamut and plausible surface colours.

    --by-illuminant: a camera's fits for several lights (D65, A, a measured light) as one config, one space per
    light, 'camcal <camera> (<light>)'.

    A studio's config given as --base in the --ocio folder is extended in place (same file, its roles, spaces
    and search paths kept).

    --base: 'camcal' (camcal's small ACES config, ocio_configs/camcal_base.ocio), an ocio:// built-in
    (default: ocio://studio-config-latest, the newest ACES studio config made for --ocio-version) or a .ocio
    file with an aces_interchange role; a base newer than --ocio-version is written at it when it uses
    nothing newer.

    --clf: the input transform from camera code values (0-1) to ACES2065-1 (linearisation, model, Bradford to the
    ACES white) as a Common LUT Format file OpenColorIO and other CLF readers load, its ProcessList id and Info's
    ACEStransformID the ACES transform ID urn:ampas:aces:transformId:v2.0:Input.camcal.<camera>_<light>_to_ACES.a2.v1.
    --amf: an ACES Metadata File (urn:ampas:aces:amf:v2.0) whose pipeline's input transform is that CLF, with
    applied="false" (or "true" with --applied). --dctl: the transform for DaVinci Resolve (ACES Transforms/IDT).
    """
    from camcal.api.colour import export_colour

    result = export_colour(
        args.fits, ocio=args.ocio, icc=args.icc, camera=args.camera_name, by_illuminant=args.by_illuminant,
        base=args.base, ocio_version=args.ocio_version, family=args.family, adaptation=args.cat,
        icc_version=args.icc_version, max_bake_error=args.max_bake_error, clf=args.clf, amf=args.amf,
        dctl=args.dctl, aces_space=args.aces_space, applied=args.applied)
    report_result(args, result, say=False)
    return 0
