"""A plate's readout time estimated over seeded draws: bias, spread against its sigma, and when it is undetermined.

The plates of ``tests/geometry/rolling_shutter_plates.py`` (640 x 360, f 500 px, 30 fps, 100 points 5-14 m
away, 0.5 px noise a coordinate, the solve imitated by the true poses and points slightly perturbed), each point
imaged on the row whose read-out time put it there: a handheld walk that pans (up to 75 deg/s) and tilts, read out
in 25 ms and in 0 ms (a global shutter), the same walk with a 3 Hz tremor (a motion whose velocity changes within a
frame interval: the model's error), and, for the undetermined case, a sideways dolly and a forward drive at a
constant speed. For each, ``camcal.geometry.rolling_shutter_ba.estimate_readout``'s mean estimate, the spread of
the estimates against their mean sigma (the printed one, and the noise's and the block jackknife's it is the larger
of), the normalised error ``z = (estimate - truth) / sigma`` (its RMS is 1 when the sigma is right) and the same
with the noise's sigma alone, the share within 1 and 2 sigma, how often it is said to be determined, the time of
one estimate and the share of it the jackknife and the fourth-order velocities' step take (under whatever load the
machine has: compare the lines of one run).

``--seeds N`` (default 20), ``--frames N`` (default 12).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import camcal.geometry.rolling_shutter_ba as rolling_shutter_ba  # noqa: E402
from camcal.geometry.rolling_shutter import camera_velocities  # noqa: E402
from tests.geometry.rolling_shutter_plates import plate  # noqa: E402

_EXTRA = [0.0]  # seconds spent in the jackknife and the fourth-order velocities


def _timed(function):
    """``function``, its time added to ``_EXTRA`` (for the fourth-order velocities only when asked for them)."""
    def timed(*args, **kwargs):
        start = time.perf_counter()
        value = function(*args, **kwargs)
        if function is not camera_velocities or kwargs.get("order") == 4:
            _EXTRA[0] += time.perf_counter() - start
        return value
    return timed


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--frames", type=int, default=12)
    args = parser.parse_args()
    rolling_shutter_ba._block_jackknife_sigma = _timed(rolling_shutter_ba._block_jackknife_sigma)
    rolling_shutter_ba.camera_velocities = _timed(camera_velocities)
    print("motion    truth ms  mean ms  spread ms  sigma ms (noise, jackknife)  RMS z (noise only)  |z|<1  |z|<2  "
          "determined  s/estimate  extra")
    for motion, truth in (("turning", 0.025), ("turning", 0.0), ("shaking", 0.025), ("sideways", 0.025),
                          ("forward", 0.025)):
        estimates, seconds, _EXTRA[0] = [], [], 0.0
        for seed in range(100, 100 + args.seeds):
            synthetic = plate(truth, motion, seed, n_frames=args.frames)
            start = time.perf_counter()
            estimates.append(rolling_shutter_ba.estimate_readout(*synthetic.estimate_arguments()))
            seconds.append(time.perf_counter() - start)
        value = np.array([e.readout_s for e in estimates]) * 1e3
        sigma, noise, jackknife = (np.array([getattr(e, name) for e in estimates]) * 1e3
                                   for name in ("sigma_s", "noise_sigma_s", "jackknife_sigma_s"))
        z, z_noise = (value - truth * 1e3) / sigma, (value - truth * 1e3) / noise
        determined = np.mean([e.determined for e in estimates])
        print(f"{motion:9s} {truth * 1e3:8.1f} {value.mean():8.2f} {value.std(ddof=1):10.2f} "
              f"{np.median(sigma):8.2f} ({np.median(noise):.2f}, {np.median(jackknife):.2f}) "
              f"{np.sqrt(np.mean(z ** 2)):8.2f} ({np.sqrt(np.mean(z_noise ** 2)):.2f}) {np.mean(abs(z) < 1):9.2f} "
              f"{np.mean(abs(z) < 2):6.2f} {determined:11.2f} {np.median(seconds):11.2f} "
              f"{_EXTRA[0] / sum(seconds):6.3f}")


if __name__ == "__main__":
    main()
