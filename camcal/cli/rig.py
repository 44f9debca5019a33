"""``camcal rig show | export | import``: read a rig file, write it for another tool, read another tool's."""

from __future__ import annotations

import argparse

from camcal.cli.options import handler, image_size, image_size_option, out_option, rig_argument, verb_group
from camcal.cli.summary import summary_of

__all__ = ["register"]


def register(parser: argparse.ArgumentParser) -> None:
    """``show``, ``export`` and ``import`` under ``camcal rig``."""
    from camcal.io.interchange import FORMATS

    verbs = verb_group(parser, "rig_verb")
    show = verbs.add_parser("show", help="print a readable summary of a rig file")
    rig_argument(show, metavar="FILE")
    show.add_argument("--validate", action="store_true",
                      help="also check FILE against the rig file's JSON Schema (docs/rig.schema.json) and say so")
    handler(show, _show)
    export = verbs.add_parser("export", help="write a rig for another tool (OpenCV, Kalibr, COLMAP, USD, Nuke)")
    rig_argument(export)
    export.add_argument("--to", required=True, choices=FORMATS, metavar="FORMAT", help=f"one of: {', '.join(FORMATS)}")
    export.add_argument("out", metavar="OUT", help="the file (a directory for colmap) to write")
    export.add_argument("--camera", action="append", metavar="NAME", help="export only this camera (repeatable)")
    export.add_argument("--stmaps", action="store_true",
                        help="usd: also write each lens' ST-maps beside the stage and reference them from its camera")
    handler(export, _export)
    imp = verbs.add_parser("import", help="read another tool's camera file as a rig")
    imp.add_argument("file", metavar="FILE", help="the other tool's file")
    imp.add_argument("--from", dest="fmt", required=True, choices=FORMATS, metavar="FORMAT",
                     help=f"one of: {', '.join(FORMATS)}")
    out_option(imp, "RIG.rig.json", "the rig file to write")
    image_size_option(imp, "usd: the image size of cameras that carry none (USD cameras not written by camcal)")
    handler(imp, _import)


def _show(args: argparse.Namespace) -> int:
    from camcal.model.rig import Rig
    from camcal.model.rig_schema import RIG_SCHEMA_ID, load_validated

    rig = load_validated(args.rig) if args.validate else Rig.load(args.rig)
    if args.validate:
        print(f"{args.rig}: valid (conforms to {RIG_SCHEMA_ID} and loads)")
    print(rig.summary())
    summary_of(args).figures(rig=rig.to_dict())
    return 0


def _print_conversions(args: argparse.Namespace, result) -> None:
    import dataclasses

    for conversion in result.conversions:
        print(conversion.describe())
    for note in result.notes:
        print(f"note: {note}")
    summary_of(args).figures(conversions=[dataclasses.asdict(c) for c in result.conversions], notes=list(result.notes))


def _export(args: argparse.Namespace) -> int:
    """Write RIG as FORMAT. opencv: .yaml/.yml/.xml FileStorage (one camera or a stereo pair); kalibr:
    camchain.yaml; colmap: a directory with cameras.txt, images.txt, points3D.txt; usd: .usda/.usdc/.usd;
    nuke: .nk. A lens or skew the format cannot hold is fitted with the nearest model it holds and the max
    pixel residual is printed; exact conversions say so.
    """
    from pathlib import Path

    from camcal.io.interchange import export_rig
    from camcal.model.rig import Rig

    result = export_rig(Rig.load(args.rig), args.to, args.out, cameras=args.camera, rig_path=args.rig,
                        stmaps=args.stmaps)
    _print_conversions(args, result)
    for path in result.paths:
        summary_of(args).wrote(path, args.to if path == Path(args.out) or path.parent == Path(args.out) else "stmap")
    return 0


def _import(args: argparse.Namespace) -> int:
    """Read FILE (a directory for colmap) written by FORMAT's tool and write a camcal rig."""
    import dataclasses
    from pathlib import Path

    from camcal.io.interchange import import_rig
    from camcal.io.ply import write_points_ply
    from camcal.model.rig import make_provenance

    result = import_rig(args.file, args.fmt,
                        image_size=None if args.image_size is None else image_size(args.image_size))
    rig = dataclasses.replace(result.rig, provenance=make_provenance("import", format=args.fmt, source=str(args.file)))
    _print_conversions(args, result)
    out = summary_of(args)
    if result.points_xyz is not None:
        points = Path(args.out).with_name(Path(args.out).name.removesuffix(".json").removesuffix(".rig") + ".points.ply")
        out.wrote(write_points_ply(points, result.points_xyz, result.points_rgb), "points")
        rig = dataclasses.replace(rig, points=points.name)
    out.figures(n_cameras=len(rig.cameras), n_frames=len(rig.frames))
    out.wrote(rig.save(args.out), "rig")
    return 0
