"""``camcal colour export``: fits as OCIO colour spaces (config + CLF) and ICC camera profiles."""

from __future__ import annotations

import argparse

from camcal.base.errors import CamcalError
from camcal.cli.options import handler, output_folder
from camcal.cli.summary import summary_of

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
                             "CY2024 and later; 2.5: Blender 5.2, CY2026)")
    parser.add_argument("--family", metavar="FAMILY",
                        help="family of the camera spaces, e.g. a studio's own 'Input/Witness' (default: Input/<maker> "
                             "from the raw capture, else Input/camcal)")
    parser.add_argument("--cat", choices=("Bradford", "CAT02"), default="Bradford",
                        help="adaptation from the fit's white to the ACES white (default: %(default)s)")
    parser.add_argument("--icc", metavar="OUT.icc", help="write an ICC camera profile (one fit only)")
    parser.add_argument("--icc-version", type=int, choices=(4, 2), default=4,
                        help="ICC profile version: 4 (ICC.1:2010, default) or 2 (ICC.1:2001-04)")
    parser.add_argument("--max-bake-error", type=float, default=0.2, metavar="DE",
                        help="largest CIEDE2000 a baked LUT may add over the chart gamut and plausible surface "
                        "colours (default: %(default)s)")
    handler(parser, _export)


def _export(args: argparse.Namespace) -> int:
    """Export characterisations (*.colour.json) as input colour spaces 'camcal <camera>' (family Input/camcal) of
    an OpenColorIO config, and/or as an ICC camera profile. Matrix fits are exact; other models are baked
    (log-chromaticity shaper + 3D LUT; ICC v4: float D2B0/D2B1 plus a 16-bit A2B0) with the bake error
    checked over the chart gamut and plausible surface colours.

    --by-illuminant: a camera's fits for several lights (D65, A, a measured light) as one config, one space per
    light, 'camcal <camera> (<light>)'.

    A studio's config given as --base in the --ocio folder is extended in place (same file, its roles, spaces
    and search paths kept).

    --base: 'camcal' (camcal's small ACES config, ocio_configs/camcal_base.ocio), an ocio:// built-in
    (default: ocio://studio-config-latest, the newest ACES studio config made for --ocio-version) or a .ocio
    file with an aces_interchange role; a base newer than --ocio-version is written at it when it uses
    nothing newer.
    """
    import dataclasses
    from pathlib import Path

    from camcal.colour.fit.record import ColourFit
    from camcal.io.colourfile import load_colour_file

    if not args.ocio and not args.icc:
        raise CamcalError("nothing to write: give --ocio OUTDIR and/or --icc OUT.icc")
    if args.camera_name and len(args.fits) > 1 and not args.by_illuminant:
        raise CamcalError(f"--camera-name needs exactly one fit (or --by-illuminant), got {len(args.fits)}")
    for option, value in (("--ocio-version", args.ocio_version), ("--family", args.family)):
        if value and not args.ocio:
            raise CamcalError(f"{option} applies to the OCIO config: give --ocio OUTDIR")
    if args.by_illuminant and not args.ocio:
        raise CamcalError("--by-illuminant names OCIO colour spaces: give --ocio OUTDIR")
    if args.icc and len(args.fits) > 1:
        raise CamcalError(f"--icc writes one profile: give one fit, got {len(args.fits)}")
    if not (args.max_bake_error > 0):
        raise CamcalError(f"--max-bake-error must be > 0, got {args.max_bake_error}")
    out = summary_of(args)
    fits, matches, lights = [], [], []
    for entry in args.fits:
        path, light = entry, None
        if args.by_illuminant and "=" in entry and not Path(entry).is_file():
            light, path = entry.split("=", 1)
            if not light.strip():
                raise CamcalError(f"empty light name in {entry!r} (expected LIGHT=FIT.colour.json)")
        fit = load_colour_file(path)
        if not isinstance(fit, ColourFit):
            if light is not None:
                raise CamcalError(f"{path} is a camera match, not a characterisation: it has no light to name")
            matches.append(fit)
            continue
        name = args.camera_name or fit.camera or Path(path).name.removesuffix(".json").removesuffix(".colour")
        fits.append((name, fit))
        lights.append(light)
    if args.by_illuminant:
        from camcal.colour.export.ocio_fit import names_by_illuminant

        fits = names_by_illuminant([(name, fit, light) for (name, fit), light in zip(fits, lights)])
    if args.icc and not fits:
        raise CamcalError("--icc needs a characterisation (kind characterisation); a camera match has no ICC profile")
    profile = None
    if args.icc:
        from camcal.colour.export.icc import icc_profile_from_fit
        from camcal.io.icc import write_icc

        profile = icc_profile_from_fit(fits[0][1], fits[0][0], version=args.icc_version,
                                       max_delta_E=args.max_bake_error)
    if args.ocio:
        from camcal.io.ocio import export_ocio

        from camcal.base.atomic import final_path

        with output_folder(args.ocio) as ocio_dir:
            version = {"ocio_version": args.ocio_version} if args.ocio_version else {}
            result = export_ocio(fits, ocio_dir, base=args.base, cat=args.cat, max_delta_E=args.max_bake_error,
                                 matches=matches, family=args.family, home=args.ocio, **version)
        result = dataclasses.replace(result, config_path=final_path(result.config_path, ocio_dir, args.ocio))
        for space in result.spaces:
            print(space.summary())
        print(f"wrote {result.config_path} (OCIO profile {result.profile_version}, base {result.base}, "
              f"{len(fits)} camera space(s), {len(matches)} match Look(s))")
        out.figures(base=result.base, ocio_profile_version=result.profile_version, n_matches=len(matches), spaces=[{
            "name": space.name, "camera": space.camera, "model": space.model, "kind": space.kind,
            "lut_size": space.lut_size, "clf": space.clf, "linearisation_error": space.linearisation_error,
            "bake_error_delta_E2000": None if space.bake_error is None else dataclasses.asdict(space.bake_error),
        } for space in result.spaces])
        out.wrote(result.config_path, "ocio config", say=False)
        for space in result.spaces:
            if space.clf:
                out.wrote(Path(args.ocio) / space.clf, "clf", say=False)
    if profile is not None:
        write_icc(profile, args.icc)
        print(f"wrote {args.icc} (ICC v{profile.version}, {profile.summary()})")
        out.figures(icc={"version": profile.version, "kind": profile.kind, "bake_error_delta_E2000":
                         None if profile.kind == "matrix-trc" else dataclasses.asdict(profile.bake_error),
                         "float_clut_size": profile.float_clut_size, "float_bake_error_delta_E2000":
                         None if profile.float_bake_error is None else dataclasses.asdict(profile.float_bake_error)})
        out.wrote(args.icc, "icc", say=False)
    return 0
