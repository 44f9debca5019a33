"""A plate's readout time estimated over seeded draws: bias, spread against its sigma, and when it is undetermined.

The plates of ``tests/geometry/rolling_shutter_plates.py`` (640 x 360, f 500 px, 30 fps, 100 points 5-14 m
away, 0.5 px noise a coordinate, the solve imitated by the true poses and points slightly perturbed), each point
imaged on the row whose read-out time put it there: a handheld walk that pans (up to 75 deg/s) and tilts, read out
in 25 ms and in 0 ms (a global shutter), and, for the undetermined case, a sideways dolly and a forward drive at a
constant speed. For each, ``camcal.geometry.rolling_shutter_ba.estimate_readout``'s mean estimate, the spread of
the estimates against their mean sigma, the normalised error ``z = (estimate - truth) / sigma`` (its RMS is 1 when
the sigma is right), the share within 1 and 2 sigma, how often it is said to be determined, and the time of one
estimate (under whatever load the machine has: compare the lines of one run).

``--seeds N`` (default 20), ``--frames N`` (default 12).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from camcal.geometry.rolling_shutter_ba import estimate_readout  # noqa: E402
from tests.geometry.rolling_shutter_plates import plate  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--frames", type=int, default=12)
    args = parser.parse_args()
    print("motion    truth ms  mean ms  spread ms  mean sigma ms  RMS z  |z|<1  |z|<2  determined  s/estimate")
    for motion, truth in (("turning", 0.025), ("turning", 0.0), ("sideways", 0.025), ("forward", 0.025)):
        estimates, seconds = [], []
        for seed in range(100, 100 + args.seeds):
            synthetic = plate(truth, motion, seed, n_frames=args.frames)
            start = time.perf_counter()
            estimates.append(estimate_readout(*synthetic.estimate_arguments()))
            seconds.append(time.perf_counter() - start)
        value = np.array([e.readout_s for e in estimates]) * 1e3
        sigma = np.array([e.sigma_s for e in estimates]) * 1e3
        z = (value - truth * 1e3) / sigma
        determined = np.mean([e.determined for e in estimates])
        print(f"{motion:9s} {truth * 1e3:8.1f} {value.mean():8.2f} {value.std(ddof=1):10.2f} {sigma.mean():14.2f} "
              f"{np.sqrt(np.mean(z ** 2)):6.2f} {np.mean(abs(z) < 1):6.2f} {np.mean(abs(z) < 2):6.2f} "
              f"{determined:11.2f} {np.median(seconds):11.2f}")


if __name__ == "__main__":
    main()
