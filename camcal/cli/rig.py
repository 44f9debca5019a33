"""``camcal rig show | export | import``: read a rig file, write it for another tool, read another tool's."""

from __future__ import annotations

import argparse

from camcal.cli.options import (handler, image_size, image_size_option, named_option, out_option, rig_argument,
                                verb_group)
from camcal.cli.summary import summary_of

__all__ = ["register"]


def register(parser: argparse.ArgumentParser) -> None:
    """``show``, ``export`` and ``import`` under ``camcal rig``."""
    from camcal.io.conversion import exactness_table
    from camcal.io.interchange import FORMATS

    verbs = verb_group(parser, "rig_verb")
    show = verbs.add_parser("show", help="print a readable summary of a rig file")
    rig_argument(show, metavar="FILE")
    show.add_argument("--validate", action="store_true",
                      help="also check FILE against the rig file's JSON Schema (docs/rig.schema.json) and say so")
    handler(show, _show, [
        "camcal rig show board.rig.json",
        "camcal rig show board.rig.json --validate",
    ])
    export = verbs.add_parser("export", help="write a rig for another tool (OpenCV, Kalibr, COLMAP, USD, Nuke, 3DE)")
    rig_argument(export, help="a *.rig.json file, or a lens profile *.profile.json (to lensfun, lens-table, "
                              "opentrackio or 3de)")
    export.add_argument("--to", choices=FORMATS + ("lens-table", "opentrackio"), metavar="FORMAT",
                        help=f"one of: {', '.join(FORMATS)}, lens-table (a lens profile sampled over its "
                        "encoders, JSON), opentrackio (a lens profile as OpenTrackIO lens samples over its encoders, "
                        "JSON; needs --sensor-width) (default: from OUT's suffix, .nk .usd* .txt)")
    export.add_argument("out", metavar="OUT", help="the file (a directory for colmap) to write")
    export.add_argument("--camera", action="append", metavar="NAME", help="export only this camera (repeatable)")
    export.add_argument("--stmaps", action="store_true",
                        help="usd: also write each lens' ST-maps beside the stage and reference them from its camera")
    export.add_argument("--sensor-width", type=float, metavar="MM",
                        help="a lens profile to opentrackio (required: its lens is in mm on the sensor) or 3de (its "
                        "film back; default 36): the sensor's active width in mm")
    named_option(export, "--vignetting", "FOCALmm@FOCUSm/fN=FLAT.json",
                 "a lens profile to lensfun: a flat field (colour flatfield --out) and the lens state and aperture "
                 "it was shot at, e.g. 24mm@1.2m/f4=flat24.json, written as a pa vignetting entry fitted about the "
                 "lens' centre (what it misses of the flat field printed); repeated or several entries; each state "
                 "inside the profile's calibrated range")
    named_option(export, "--tca", "FOCALmm=GLOB",
                 "a lens profile to lensfun: 8-bit colour images of the profile's board shot at a focal length, e.g. "
                 "24mm='tca/24/*.png', its lateral chromatic aberration (red and blue against green, each corner "
                 "found in every channel) written as a poly3 TCA entry about the lens' centre (the corners' residual "
                 "printed); repeated or several entries")
    handler(export, _export, [
        "camcal rig export board.rig.json --to opencv board.yaml",
        "camcal rig export board.rig.json board.nk --camera left",
        "# a USD stage whose cameras reference their lens' ST-maps",
        "camcal rig export solve/solve.rig.json solve.usda --stmaps",
        "# a lens profile as a Lensfun lens, one entry per focal length calibrated",
        "camcal rig export lens.profile.json lens.xml --to lensfun",
        "# with the vignetting of grey cards shot at two lens states (colour flatfield --out)",
        "camcal rig export lens.profile.json lens.xml --to lensfun --vignetting 24mm@1.2m/f4=flat24.json "
        "70mm@inf/f4=flat70.json",
        "# and the lateral chromatic aberration of colour board images at two focal lengths",
        "camcal rig export lens.profile.json lens.xml --to lensfun --tca 24mm='tca/24/*.png' 70mm='tca/70/*.png'",
        "# a lens profile as OpenTrackIO lens samples, and as 3DEqualizer dynamic distortion",
        "camcal rig export lens.profile.json lens.json --to opentrackio --sensor-width 36",
        "camcal rig export lens.profile.json lens.txt --to 3de",
    ], notes=["Which lens each format holds exactly:\n" + exactness_table()])
    imp = verbs.add_parser("import", help="read another tool's camera file as a rig")
    imp.add_argument("file", metavar="FILE", help="the other tool's file")
    imp.add_argument("--from", dest="fmt", choices=FORMATS + ("opentrackio",), metavar="FORMAT",
                     help=f"one of: {', '.join(FORMATS)}, opentrackio (camcal's OpenTrackIO lens samples: a frame "
                     "per lens state) (default: from FILE's suffix, .nk .usd* .txt)")
    out_option(imp, "RIG.rig.json", "the rig file to write")
    image_size_option(imp, "usd, 3de, nuke: the image size of cameras that carry none (USD cameras, 3DE lens "
                           "files and LDPK nodes not written by camcal)")
    handler(imp, _import, [
        "camcal rig import board.yaml --from opencv --out board.rig.json",
        "camcal rig import shotcam.usda --image-size 1920 1080 --out shotcam.rig.json",
    ])


def _show(args: argparse.Namespace) -> int:
    from camcal.api.rig import load_rig
    from camcal.model.rig_schema import RIG_SCHEMA_ID, load_validated

    rig = load_validated(args.rig) if args.validate else load_rig(args.rig)
    if args.validate:
        print(f"{args.rig}: valid (conforms to {RIG_SCHEMA_ID} and loads)")
    print(rig.summary())
    summary_of(args).figures(rig=rig.to_dict())
    return 0


def _print_conversions(args: argparse.Namespace, conversions, notes) -> None:
    import dataclasses

    for conversion in conversions:
        print(conversion.describe())
    for note in notes:
        print(f"note: {note}")
    summary_of(args).figures(conversions=[dataclasses.asdict(c) for c in conversions], notes=list(notes))


def _export(args: argparse.Namespace) -> int:
    """Write RIG as FORMAT. opencv: .yaml/.yml/.xml FileStorage (one camera or a stereo pair); kalibr:
    camchain.yaml; colmap: a directory with cameras.txt, images.txt, points3D.txt; usd: .usda/.usdc/.usd;
    nuke: .nk; 3de: a 3DEqualizer lens file (.txt, one camera; from a lens profile, its dynamic distortion over
    focal length and focus distance). A lens profile also goes to lens-table and opentrackio (OpenTrackIO lens
    samples, Brown-Conrady in mm on a sensor --sensor-width wide); to lensfun with the vignetting of flat fields
    per lens state (--vignetting) and the lateral chromatic aberration of colour board images per focal length
    (--tca). A lens or skew the format cannot hold is
    fitted with the nearest model it holds and its pixel residual is printed (for the 3DEqualizer models:
    max and RMS inside the image and over a 1.25 overscan border); exact conversions say so.
    """
    from pathlib import Path

    from camcal.api.rig import export_rig
    from camcal.io.interchange import format_of

    fmt = format_of(args.out, args.to)
    result = export_rig(args.rig, args.out, fmt, cameras=args.camera, stmaps=args.stmaps,
                        sensor_width_mm=args.sensor_width, vignetting=args.vignetting, tca=args.tca)
    _print_conversions(args, result.conversions, result.notes)
    for path in result.paths:
        summary_of(args).wrote(path, fmt if path == Path(args.out) or path.parent == Path(args.out) else "stmap")
    return 0


def _import(args: argparse.Namespace) -> int:
    """Read FILE (a directory for colmap) written by FORMAT's tool and write a camcal rig."""
    from camcal.api.rig import import_rig

    imported = import_rig(args.file, args.fmt,
                          image_size=None if args.image_size is None else image_size(args.image_size))
    _print_conversions(args, imported.conversions, imported.notes)
    out = summary_of(args)
    files = imported.save(args.out)
    for path, kind in files[:-1]:
        out.wrote(path, kind)
    out.figures(n_cameras=len(imported.rig.cameras), n_frames=len(imported.rig.frames))
    out.wrote(files[-1][0], "rig")
    return 0
