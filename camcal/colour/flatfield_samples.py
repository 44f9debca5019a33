"""Flat-field samples: grey-card images reduced to block values, or neutral patches at their positions.

What :func:`camcal.colour.flatfield.fit_flat_field` fits: linear RGB at pixel
positions with the shot (photo) and the neutral patch each comes from and its
relative noise. A grey card becomes one sample per block of pixels
(``BLOCKS_ACROSS`` across the longer side): the mean of the block's pixels
within 4 sigma of its median (a sigma-clipped mean: robust to dust and hot
pixels, more efficient than the median on shot noise), its noise from the
block's MAD (1.4826 MAD, the normal distribution's sigma). Blocks that are not
one surface (the card's edge, texture, the wall behind) are left out here or
rejected by the fit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from camcal.base.errors import CamcalError

__all__ = ["BLOCKS_ACROSS", "MIN_SIGNAL_TO_NOISE", "MIN_VALID_FRACTION", "ONE_SURFACE", "FlatFieldSamples",
           "check_image", "samples_from_images", "samples_from_patches"]

#: Blocks across the longer side when images are reduced to samples.
BLOCKS_ACROSS = 48
#: A block is used when at least this fraction of its pixels is valid.
MIN_VALID_FRACTION = 0.5
#: A block is one surface when this fraction of its pixels is within 4 sigma of its median.
ONE_SURFACE = 0.97
#: A card is too dark when its level is below this many times its pixel noise.
MIN_SIGNAL_TO_NOISE = 20.0
_CHANNELS = 3


def check_image(image: NDArray, what: str) -> None:
    """Refuse anything but an ``(H, W, 3)`` image of at least 2 x 2 pixels, naming ``what``."""
    if image.ndim != 3 or image.shape[2] != _CHANNELS or min(image.shape[:2]) < 2:
        raise CamcalError(f"{what}: expected an (H, W, 3) RGB image, got shape {image.shape}")


@dataclass(frozen=True)
class FlatFieldSamples:
    """What a flat field is fitted to: linear RGB at pixel positions, with their shot and patch.

    Attributes
    ----------
    xy : (N, 2) ndarray
        Pixel positions.
    RGB : (N, 3) ndarray
        Linear values (> 0).
    shot, patch : (N,) int ndarray
        The shot (image) and the neutral patch of each sample (0-based, each from 0 without gaps; a grey
        card is patch 0).
    sigma : (N, 3) ndarray
        Standard deviation of ``log RGB`` (the sample's relative noise).
    image_size : (int, int)
    """

    xy: NDArray[np.float64]
    RGB: NDArray[np.float64]
    shot: NDArray[np.int64]
    patch: NDArray[np.int64]
    sigma: NDArray[np.float64]
    image_size: tuple[int, int]

    def subset(self, keep: NDArray) -> FlatFieldSamples:
        """The samples where ``keep`` is true."""
        return FlatFieldSamples(self.xy[keep], self.RGB[keep], self.shot[keep], self.patch[keep], self.sigma[keep],
                                self.image_size)


def samples_from_images(images: list[NDArray], masks: list[NDArray | None] | None = None, *,
                        clip: float | None = None, names: list[str] | None = None) -> FlatFieldSamples:
    """Grey-card images as samples: the median of each block of pixels (``BLOCKS_ACROSS`` across).

    Parameters
    ----------
    images : list of (H, W, 3) ndarray
        Linear RGB of a grey card, one size; each image is a shot (its exposure is fitted).
    masks : list of (H, W) bool ndarray or None, optional
        The card's pixels per image (None: every pixel; blocks that are not card are rejected by the fit).
    clip : float, optional
        Pixels with a channel at or above this value are left out (clipped).
    names : list of str, optional
        The images' names for the messages.

    Returns
    -------
    FlatFieldSamples
        One sample per block with at least ``MIN_VALID_FRACTION`` of its pixels valid: the mean of its pixels
        within 4 sigma of its median; blocks whose relative spread is four times that of the quietest
        quarter of the blocks (the card's, when it fills a quarter of the frame or more), or with fewer than
        ``ONE_SURFACE`` of their pixels within 4 sigma (the card's edge, texture), are left out.

    Raises
    ------
    CamcalError
        Images of different sizes, not RGB, or a card too dark: in the quietest tenth of the blocks, a level
        not positive or below ``MIN_SIGNAL_TO_NOISE`` times the pixel noise.
    """
    if not images:
        raise CamcalError("no grey-card image given")
    names = names or [f"image {i + 1}" for i in range(len(images))]
    masks = masks or [None] * len(images)
    if len(masks) != len(images):
        raise CamcalError(f"got {len(masks)} masks for {len(images)} images")
    height, width = np.asarray(images[0]).shape[:2]
    for image, name in zip(images, names):
        image = np.asarray(image)
        check_image(image, name)
        if image.shape[:2] != (height, width):
            raise CamcalError(f"the grey-card images differ in size: {names[0]} is {width}x{height} px, {name} is "
                              f"{image.shape[1]}x{image.shape[0]} px")
    block = max(2, math.ceil(max(width, height) / BLOCKS_ACROSS))
    nx, ny = width // block, height // block
    x0, y0 = (width - nx * block) // 2, (height - ny * block) // 2
    inside = (slice(y0, y0 + ny * block), slice(x0, x0 + nx * block))
    grid_y, grid_x = np.mgrid[inside].astype(np.float64)

    def blocks(array: NDArray) -> NDArray:
        """``(ny * block, nx * block[, C])`` -> ``(ny * nx, block * block, C)``."""
        array = array.reshape(array.shape[:2] + (-1,))
        c = array.shape[2]
        return array.reshape(ny, block, nx, block, c).transpose(0, 2, 1, 3, 4).reshape(ny * nx, block * block, c)

    xy_all, RGB_all, shot_all, sigma_all = [], [], [], []
    for index, (image, mask, name) in enumerate(zip(images, masks, names)):
        crop = np.asarray(image, dtype=np.float64)[inside]
        valid = np.all(np.isfinite(crop), axis=2)
        if clip is not None:
            valid &= np.all(crop < clip, axis=2)
        if mask is not None:
            mask = np.asarray(mask, dtype=bool)
            if mask.shape != (height, width):
                raise CamcalError(f"the mask of {name} is {mask.shape[1]}x{mask.shape[0]} px, the image "
                                  f"{width}x{height} px")
            valid &= mask[inside]
        n_valid = blocks(valid)[:, :, 0].sum(axis=1)
        used = n_valid >= MIN_VALID_FRACTION * block * block
        if not np.any(used):
            raise CamcalError(f"{name}: no valid pixels (all clipped, masked or not finite)")
        pixels = blocks(np.where(valid[..., None], crop, np.nan))[used]
        n_valid = n_valid[used]
        level = np.nanmedian(pixels, axis=1)
        # the code step (quantisation: an 8-bit card may sit on one or two code values, MAD 0), then the noise:
        # 1.4826 MAD, at least the step's own (step / sqrt(12))
        with np.errstate(invalid="ignore"):
            steps = np.diff(np.sort(pixels, axis=1), axis=1)
        step = np.min(np.where(steps > 0, steps, np.inf), axis=1)
        step = np.where(np.isfinite(step), step, 0.0)
        noise = np.maximum(1.4826 * np.nanmedian(np.abs(pixels - level[:, None, :]), axis=1), step / math.sqrt(12))
        # the card: the quietest blocks (a tenth of them), whatever surrounds it
        quiet = np.argsort(np.max(noise / np.maximum(level, 1e-12), axis=1))[: max(1, len(level) // 10)]
        card_level, card_noise = np.median(level[quiet], axis=0), np.median(noise[quiet], axis=0)
        if not (np.all(card_level > 0.0) and np.all(card_level >= MIN_SIGNAL_TO_NOISE * card_noise)):
            raise CamcalError(
                f"{name} is too dark for a flat field: the card's median level R G B "
                f"{' '.join(f'{v:.3g}' for v in card_level)} against pixel noise "
                f"{' '.join(f'{v:.3g}' for v in card_noise)} (needs > 0 and {MIN_SIGNAL_TO_NOISE:g} times the "
                "noise); expose the card 1 to 2 stops below clipping")
        relative = noise / np.maximum(level, 1e-12)
        # one surface: the block's spread is the card's and its pixels lie within 4 sigma of its median (a block
        # over the card's edge holds another surface, which moves its median though not its MAD)
        near = np.all(np.abs(pixels - level[:, None, :]) <= np.maximum(4.0 * noise, step)[:, None, :], axis=2)
        n_near = near.sum(axis=1)
        typical = np.percentile(relative, 25, axis=0)  # the card's, when it covers a quarter of the frame or more
        smooth = (np.all(level > 0.0, axis=1) & np.all(relative <= 4.0 * typical + 1e-6, axis=1)
                  & (n_near >= ONE_SURFACE * n_valid))
        # the block's value: the mean of its pixels within 4 sigma of its median (a sigma-clipped mean, more
        # efficient than the median on shot noise)
        level = np.where(smooth[:, None], np.nansum(np.where(near[..., None], pixels, 0.0), axis=1)
                         / np.maximum(n_near, 1)[:, None], level)
        weights = blocks(valid)[used][:, :, 0]
        bx = (blocks(grid_x)[used][:, :, 0] * weights).sum(axis=1) / n_valid
        by = (blocks(grid_y)[used][:, :, 0] * weights).sum(axis=1) / n_valid
        xy_all.append(np.column_stack([bx, by])[smooth])
        RGB_all.append(level[smooth])
        shot_all.append(np.full(int(smooth.sum()), index, dtype=np.int64))
        # the mean's standard deviation, relative (sigma / sqrt(n)), floored for noiseless renders
        sigma_all.append(np.maximum(relative[smooth] / np.sqrt(n_near[smooth, None]), 1e-5))
    shots = np.concatenate(shot_all)
    return FlatFieldSamples(np.concatenate(xy_all), np.concatenate(RGB_all), shots, np.zeros_like(shots),
                            np.concatenate(sigma_all), (int(width), int(height)))


def samples_from_patches(xy: NDArray, RGB: NDArray, patch: NDArray, image_size: tuple[int, int], *,
                         shot: NDArray | None = None, sigma: NDArray | float = 0.002) -> FlatFieldSamples:
    """Neutral patches seen at several places in the frame as samples.

    Parameters
    ----------
    xy : (N, 2) ndarray
        Each patch's centre in pixels.
    RGB : (N, 3) ndarray
        Its linear value (mean over the patch).
    patch : (N,) ndarray of int or str
        Which neutral patch (the same patch at several places is what ties the falloff together).
    image_size : (int, int)
    shot : (N,) ndarray, optional
        The photo each sample comes from (default: one exposure for all).
    sigma : float or (N, 3) ndarray
        Relative noise of each value (default 0.2 %).

    Returns
    -------
    FlatFieldSamples
    """
    xy, RGB = np.asarray(xy, dtype=np.float64), np.asarray(RGB, dtype=np.float64)
    if xy.ndim != 2 or xy.shape[1] != 2 or RGB.shape != (len(xy), _CHANNELS):
        raise CamcalError(f"patches: expected (N, 2) positions and (N, 3) values, got {xy.shape} and {RGB.shape}")
    if len(xy) == 0 or not (np.all(np.isfinite(xy)) and np.all(np.isfinite(RGB))):
        raise CamcalError("patches: positions and values must be given and finite")
    if np.any(RGB <= 0.0):
        raise CamcalError(f"patches: {int(np.sum(np.any(RGB <= 0, axis=1)))} patch value(s) are <= 0 (a flat "
                          "field needs linear values above black)")
    _, patch_index = np.unique(np.asarray(patch), return_inverse=True)
    _, shot_index = np.unique(np.zeros(len(xy), dtype=np.int64) if shot is None else np.asarray(shot),
                              return_inverse=True)
    sigma = np.broadcast_to(np.asarray(sigma, dtype=np.float64), RGB.shape).copy()
    return FlatFieldSamples(xy, RGB, shot_index.astype(np.int64), patch_index.astype(np.int64), sigma,
                            (int(image_size[0]), int(image_size[1])))
