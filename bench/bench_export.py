"""Applying a camera's exported colour transform to a 3840x2160 float frame.

Ours: camcal's numpy ``fit.apply_codes`` (linearisation + model, to XYZ).
Peer: OpenColorIO's CPU processor of the exported colour space ``camcal
nikon`` (to CIE XYZ D65 in camcal's base config): exact ops for a matrix
fit, shaper + tetrahedral Lut3D for a root-polynomial fit.

Prints ``name: ours X, peer Y, ratio Y/X`` (seconds per frame) and the
largest CIEDE2000 between the two on the frame's in-gamut pixels.
"""

import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "colour"))

from camcal.colour.evaluate import delta_E  # noqa: E402
from camcal.colour.export_ocio import export_ocio  # noqa: E402
from colour_export_helpers import codes_of, make_fit  # noqa: E402
from conftest import make_sim  # noqa: E402

SIZE = (2160, 3840)
REPEATS = 3


def _time(function, repeats=REPEATS):
    function()
    start = time.perf_counter()
    for _ in range(repeats):
        function()
    return (time.perf_counter() - start) / repeats


def main() -> int:
    import PyOpenColorIO as ocio

    sim = make_sim()
    rng = np.random.default_rng(0)
    # a frame of plausible camera colours: the independent patches with noise, as code values
    picks = sim.RGB_test[rng.integers(0, len(sim.RGB_test), SIZE[0] * SIZE[1])]
    frame = codes_of(picks * rng.uniform(0.5, 1.2, (picks.shape[0], 1))).astype(np.float32).reshape(*SIZE, 3)
    for model in ("matrix3x3", "root-polynomial:2"):
        fit = make_fit(sim, model)
        with tempfile.TemporaryDirectory() as folder:
            result = export_ocio([("nikon", fit)], folder, base="camcal")
            config = ocio.Config.CreateFromFile(str(result.config_path))
            cpu = config.getProcessor("camcal nikon", "CIE XYZ-D65 - Scene-referred").getDefaultCPUProcessor()
            work = frame.copy()

            def peer():
                work[...] = frame
                cpu.applyRGB(work)

            ours = _time(lambda: fit.apply_codes(frame.reshape(-1, 3)))
            peer_s = _time(peer)
            check = delta_E(work.reshape(-1, 3)[::97], fit.apply_codes(frame.reshape(-1, 3)[::97]),
                            fit.target_white_XYZ)
        kind = result.spaces[0].kind + (f" {result.spaces[0].lut_size}^3" if result.spaces[0].lut_size else "")
        print(f"{model} ({kind}) on a 3840x2160 float frame: ours {ours:.3f} s, peer {peer_s:.3f} s, "
              f"ratio {peer_s / ours:.2f}")
        print(f"  OCIO vs numpy on the frame: CIEDE2000 max {check.max():.3f}, mean {check.mean():.4f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
