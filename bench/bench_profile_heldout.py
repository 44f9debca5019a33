"""A zoom lens profile at held-out lens states over seeded draws: how often its 2-sigma covers and how it reprojects.

The setting of ``tests/test_zoom_lens_render.py``: Lensfun's Nikon AF-S DX
17-55mm f/2.8G (breathing with focus and its principal point drifting, as
constructed there), 10 states calibrated into a profile through
``camcal.calibrate_profile``, 3 held out. The rendered test is one draw;
here each seed draws new board poses and new corner noise (the truth's
projected corners plus Gaussian noise, no rendering) and prints, per
held-out state and over all, the share of draws where the profile's
projection is within 2 of its sigma over >= 95 % of the image and where its
held-out reprojection is <= 1.1x a direct calibration's, and the medians of
both figures.

Note the first target's floor: the error of a whole profile state is one
draw, so the image's pixels pass or fail together. Even an exact Gaussian
sigma (the worst direction's, per pixel) puts a 2-D error within 2 sigma
with a probability between 86 % (isotropic: chi-square of 2 degrees of
freedom below 4) and 95 % (one direction): a state fails now and then by
chance alone.

``--seeds N`` (default 30), ``--noise PX`` (default the renders' detection
spread), ``--views N`` a state (default 4).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from tests.test_zoom_lens_render import DETECTION_NOISE_PX, FAST_VIEWS, synthetic_figures  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=30)
    parser.add_argument("--noise", type=float, default=DETECTION_NOISE_PX)
    parser.add_argument("--views", type=int, default=FAST_VIEWS)
    args = parser.parse_args()
    rows: dict[str, list[tuple[float, float]]] = {}
    for seed in range(args.seeds):
        for label, figures in synthetic_figures(args.noise, args.views, seed=1000 * seed).items():
            rows.setdefault(label, []).append((figures["within"], figures["ratio"]))
    print(f"{args.seeds} draws, {args.views} views a state, {args.noise:g} px of corner noise a axis")
    print("held-out state: draws within 2 sigma over >= 95 % | ratio <= 1.1 | both; median share within; median ratio")
    every = []
    for label, values in rows.items():
        within, ratio = np.array(values).T
        every.append(np.column_stack([within, ratio]))
        print(f"  {label}: {np.mean(within >= 0.95):.0%} | {np.mean(ratio <= 1.1):.0%} | "
              f"{np.mean((within >= 0.95) & (ratio <= 1.1)):.0%}; {np.median(within):.1%}; {np.median(ratio):.3f}")
    within, ratio = np.concatenate(every).T
    print(f"  all: {np.mean(within >= 0.95):.1%} | {np.mean(ratio <= 1.1):.1%} | "
          f"{np.mean((within >= 0.95) & (ratio <= 1.1)):.1%}")


if __name__ == "__main__":
    main()
