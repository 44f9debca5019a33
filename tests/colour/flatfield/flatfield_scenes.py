"""A grey card photographed through a lens with known vignetting: the truth and its rendering, seeded."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from camcal.colour.flatfield import FlatField

SIZE = (960, 640)
#: Per-channel pa terms (R, G, B: more falloff in red, colour shading) and the optical centre's offset in pixels.
K_TRUE = np.array([[-0.35, 0.08, -0.03], [-0.30, 0.05, -0.02], [-0.25, 0.03, -0.01]])
CENTRE_OFFSET = np.array([18.0, -11.0])
#: The card's linear RGB at the optical centre, and electrons per unit value (shot noise: 0.4 * 20000 = 8000 e-).
CARD = np.array([0.36, 0.40, 0.32])
ELECTRONS = 20000.0


def true_flat(k: np.ndarray = K_TRUE, size: tuple[int, int] = SIZE) -> FlatField:
    """The lens's flat field: ``k`` about the image centre moved by ``CENTRE_OFFSET``."""
    width, height = size
    return FlatField(size, np.array([(width - 1) / 2, (height - 1) / 2]) + CENTRE_OFFSET, np.asarray(k, float))


@dataclass(frozen=True)
class GreyCard:
    image: np.ndarray  # (H, W, 3) linear RGB with shot noise
    card: np.ndarray  # (H, W) bool: where the card is
    gain: np.ndarray  # (H, W, 3) the true falloff


def render_grey_card(seed: int = 0, *, k: np.ndarray = K_TRUE, size: tuple[int, int] = SIZE,
                     coverage: float = 0.8, exposure: float = 1.0, electrons: float = ELECTRONS) -> GreyCard:
    """A grey card covering ``coverage`` of the frame (a centred rectangle of the frame's shape), a textured
    darker wall around it, both lit evenly and seen through the lens' falloff, with Poisson shot noise."""
    rng = np.random.default_rng(seed)
    width, height = size
    gain = true_flat(k, size).gain().astype(np.float64)
    margin_x, margin_y = (round(n * (1 - np.sqrt(coverage)) / 2) for n in (width, height))
    card = np.zeros((height, width), bool)
    card[margin_y : height - margin_y, margin_x : width - margin_x] = True
    wall = 0.12 * (1.0 + 0.5 * rng.random((height, width, 1))) * np.array([1.1, 1.0, 0.8])
    scene = np.where(card[..., None], CARD, wall) * exposure
    image = rng.poisson(scene * gain * electrons) / electrons
    return GreyCard(image, card, gain)
