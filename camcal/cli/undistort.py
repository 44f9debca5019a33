"""``camcal undistort``: undistorted images of a rig camera and the rig of the new pinhole camera."""

from __future__ import annotations

import argparse

from camcal.base.errors import CamcalError
from camcal.cli.options import (camera_option, every_option, handler, images_option, max_fov_option, out_option,
                                rig_argument, sigma_options, undistort_mode_options)
from camcal.cli.summary import summary_of

__all__ = ["register"]


def register(parser: argparse.ArgumentParser) -> None:
    """The options of ``camcal undistort``."""
    rig_argument(parser)
    camera_option(parser)
    images_option(parser, "FILE|VIDEO", "image files (repeatable), or videos (frame k of clip.mp4 written as "
                  "clip_00000k.png)")
    every_option(parser)
    undistort_mode_options(parser, "crop: no black borders; keep: every source pixel kept (bigger canvas); "
                           "overscan: canvas --overscan times the plate (default: crop)")
    max_fov_option(parser, "crop / keep: widest full angle about the axis the pinhole output holds "
                   "(default: 120 for a kannala-brandt fisheye, no cap for the other lenses)")
    out_option(parser, "DIR", "the folder to write the undistorted images and undistorted.rig.json into")
    sigma_options(parser, "DIR/sigma.exr, pixel for pixel with the undistorted images: the projection sigma "
                  "(plate pixels) of the plate pixel each one samples")
    handler(parser, _undistort, [
        "camcal undistort board.rig.json --camera left --images plates/left_0001.png "
        "plates/left_0002.png --out undistorted",
        "camcal undistort board.rig.json --camera left --images take1.mp4 --every 5 --mode overscan "
        "--overscan 1.2 --out undistorted",
    ])


def _undistort(args: argparse.Namespace) -> int:
    """Undistort images with one remap per image; writes them under their own names and DIR/undistorted.rig.json
    with the new K and distortion none. Videos are streamed, one frame at a time (--every N: frames 0, N, 2N...).
    """
    from camcal.io.video import is_video
    from camcal.pipelines.undistort import undistort_images, undistort_videos, write_undistorted_sigma
    from camcal.model.rig import Rig

    if args.every < 1:
        raise CamcalError(f"--every must be 1 or more, got {args.every}")
    videos = [path for path in args.images if is_video(path)]
    if videos and len(videos) != len(args.images):
        raise CamcalError("give images or videos, not both (undistort them in two runs)")
    rig = Rig.load(args.rig)
    if videos:
        rig_path, written = undistort_videos(rig, args.camera, videos, args.out, args.every, args.mode,
                                             args.overscan, args.max_fov)
    else:
        rig_path, written = undistort_images(rig, args.camera, args.images, args.out, args.mode, args.overscan,
                                             args.max_fov)
    camera = Rig.load(rig_path).camera(args.camera)
    width, height = camera.image_size
    print(f"undistorted {len(written)} {'frame' if videos else 'image'}(s) of {args.camera!r} ({args.mode}): {width}x{height} px, "
          f"fx {camera.K[0, 0]:.3f} fy {camera.K[1, 1]:.3f} principal point ({camera.K[0, 2]:.2f}, {camera.K[1, 2]:.2f})")
    print(f"wrote {rig_path} and {len(written)} image(s) in {args.out}")
    out = summary_of(args)
    out.figures(camera=args.camera, mode=args.mode, image_size=[width, height], K=camera.K)
    out.wrote(rig_path, "rig", say=False)
    out.wrote_each(written, "image")
    if args.sigma:
        path, sigma = write_undistorted_sigma(rig, args.camera, args.out, args.mode, args.overscan, args.max_fov,
                                              args.distance)
        print(sigma.describe())
        out.figures(sigma=sigma.to_dict())
        out.wrote(path, "sigma")
    return 0
