"""Flat-field steps from files: grey-card images or a neutral-patch CSV in, a fitted flat field out.

- :func:`flat_field_from_image_files`: read grey cards as linear RGB
  (:func:`camcal.io.flatfield.read_linear_image`), reduce them to block
  samples and fit (:mod:`camcal.colour.flatfield`);
- :func:`flat_field_from_patch_file`: neutral patches seen at several
  places in the frame, from a CSV ``x,y,R,G,B,patch[,shot]``.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from camcal.base.errors import CamcalError
from camcal.base.globs import file_or_glob
from camcal.colour.flatfield import FlatField, fit_flat_field, samples_from_images, samples_from_patches
from camcal.io.flatfield import read_linear_image, read_neutral_patches

__all__ = ["expand_images", "flat_field_from_image_files", "flat_field_from_patch_file"]


def expand_images(images: Sequence[str | os.PathLike] | str | os.PathLike) -> list[Path]:
    """Files and globs (``grey/*.exr``) as the sorted files they name; each glob must match a file, each file exist."""
    entries = [images] if isinstance(images, (str, os.PathLike)) else list(images)
    files = [Path(path) for entry in entries for path in file_or_glob("--images", entry, what="image")]
    if not files:
        raise CamcalError("no grey-card image given (--images)")
    return files


def flat_field_from_image_files(images: Sequence[str | os.PathLike] | str | os.PathLike, *,
                                mask: str | os.PathLike | None = None, linear: bool = False,
                                smooth_degree: int = 0, fit_centre: bool = True) -> tuple[FlatField, list[Path]]:
    """Fit a flat field to grey-card images (files or globs); the fit and the files read.

    Parameters
    ----------
    images : path, glob or sequence of them
        Grey cards, one size, linear (raw, EXR, 16-bit or float TIFF; 8-bit only with ``linear``).
    mask : path, optional
        An image (any format) whose non-zero pixels are the card, for every image.
    linear : bool
        The 8-bit images hold linear values.
    smooth_degree, fit_centre
        See :func:`camcal.colour.flatfield.fit_flat_field`.
    """
    from camcal.io.frames import imread

    files = expand_images(images)
    read = [read_linear_image(path, linear=linear) for path in files]
    masks = None
    if mask is not None:
        pixels = imread(mask)
        card = (pixels if pixels.ndim == 2 else pixels.max(axis=2)) > 0
        masks = [card] * len(read)
    clips = {image.clip for image in read}
    clip = min((c for c in clips if c is not None), default=None)
    samples = samples_from_images([image.RGB for image in read], masks, clip=clip, names=[str(p) for p in files])
    return fit_flat_field(samples, smooth_degree=smooth_degree, fit_centre=fit_centre, source="grey card"), files


def flat_field_from_patch_file(path: str | os.PathLike, image_size: tuple[int, int], *, smooth_degree: int = 0,
                               fit_centre: bool = True) -> FlatField:
    """Fit a flat field to neutral patches at several places: a CSV ``x,y,R,G,B,patch[,shot]``.

    ``x, y``: the patch's centre in pixels (pixel (0, 0) the centre of the top-left pixel); ``R, G, B``: its
    linear value; ``patch``: which neutral patch (a name); ``shot``: which photo (optional).
    """
    patches = read_neutral_patches(path)
    samples = samples_from_patches(patches.xy, patches.RGB, np.array(patches.patch), image_size,
                                   shot=None if patches.shot is None else np.array(patches.shot))
    return fit_flat_field(samples, smooth_degree=smooth_degree, fit_centre=fit_centre, source="neutral patches")
