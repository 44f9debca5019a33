"""``camcal sigma``: the projection-sigma map (EXR) of a rig camera, from the covariance in its rig file."""

from __future__ import annotations

import argparse

from camcal.cli.options import camera_option, distance_option, handler, rig_argument
from camcal.cli.summary import summary_of

__all__ = ["register"]


def register(parser: argparse.ArgumentParser) -> None:
    """The options of ``camcal sigma``."""
    rig_argument(parser)
    camera_option(parser)
    distance_option(parser)
    parser.add_argument("--out", required=True, metavar="SIGMA.EXR",
                        help="one-channel float EXR, plate-sized (pixel for pixel with the plate and the "
                             "camera's redistort ST-map)")
    parser.add_argument("--heatmap", metavar="FILE.png",
                        help="also write the map as a heat map PNG, pixel for pixel (viridis from 0 to its worst "
                             "value): the Blender add-on shows it as the camera's background overlay")
    handler(parser, _sigma, [
        "camcal sigma board.rig.json --camera left --out left_sigma.exr --heatmap left_sigma.png",
        "camcal sigma board.rig.json --camera left --distance 2 --out left_sigma_2m.exr",
    ])


def _sigma(args: argparse.Namespace) -> int:
    """Write the worst-direction sigma (pixels) of the projection of the ray through each pixel."""
    from camcal.geometry.uncertainty import projection_sigma_map, summarise_sigma
    from camcal.io.stmap import write_sigma_map
    from camcal.model.rig import Rig

    camera = Rig.load(args.rig).camera(args.camera)
    sigma = projection_sigma_map(camera, args.distance)
    summary = summarise_sigma(sigma, args.distance)
    path = write_sigma_map(args.out, sigma)
    heatmap = None
    if args.heatmap:
        from camcal.report.sigma import write_heatmap_png

        heatmap = write_heatmap_png(sigma, args.heatmap)
    print(f"{args.camera}: {summary.describe()}")
    out = summary_of(args)
    out.figures(camera=args.camera, sigma=summary.to_dict())
    out.wrote(path, "sigma")
    if heatmap is not None:
        out.wrote(heatmap, "heatmap")
    return 0
