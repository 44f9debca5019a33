"""Applying a camera's colour fit to a 3840x2160 float frame: camcal's apply paths vs OCIO's own processor.

For a matrix fit (exact MatrixTransform) and a root-polynomial fit (the
baked log-chromaticity Lut3D), same frame, same run:

- library: ``fit_processor(fit, "ACEScg").apply(frame, in_place=True)``;
- batch: the colour step of ``camcal batch`` (``ColourStep.apply``);
- peer: OCIO's CPU processor of the same transform, called directly
  (``cpu.applyRGB`` on the frame) - the processor both of ours use, so the
  ratio shows what camcal adds around it (>= 0.9 expected);
- numpy: the path before (``fit.apply_codes`` then the output matrix),
  printed for comparison.

Prints ``name: ours X, peer Y, ratio Y/X`` (seconds per frame) and the
largest CIEDE2000 between the OCIO path and numpy on the frame's pixels.
"""

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "colour"))

from camcal.pipelines.batch import ColourStep  # noqa: E402
from camcal.colour.difference import delta_E  # noqa: E402
from camcal.colour.export.ocio_fit import fit_processor, output_matrix  # noqa: E402
from colour_export_helpers import codes_of, make_fit  # noqa: E402
from conftest import make_sim  # noqa: E402

SIZE = (2160, 3840)
REPEATS = 3
SPACE = "ACEScg"


def _time(function, frame, repeats=REPEATS):
    """Seconds per call, each call on a fresh copy of the frame (the copy is not timed)."""
    best = []
    for _ in range(repeats + 1):
        work = frame.copy()
        start = time.perf_counter()
        function(work)
        best.append(time.perf_counter() - start)
    return float(np.median(best[1:]))


def main() -> int:
    sim = make_sim()
    rng = np.random.default_rng(0)
    # a frame of plausible camera colours: the independent patches with exposure changes, as code values
    picks = sim.RGB_test[rng.integers(0, len(sim.RGB_test), SIZE[0] * SIZE[1])]
    frame = codes_of(picks * rng.uniform(0.5, 1.2, (picks.shape[0], 1))).astype(np.float32).reshape(*SIZE, 3)
    for model in ("matrix3x3", "root-polynomial:2"):
        fit = make_fit(sim, model)
        processor = fit_processor(fit, SPACE)
        step = ColourStep(fit, SPACE)
        out = output_matrix(fit.target_white_XYZ, SPACE)

        def library(work):
            processor.apply(work, in_place=True)

        def batch(work):
            step.apply(work)

        def peer(work):
            processor.cpu.applyRGB(work)

        def numpy_path(work):
            return fit.apply_codes(work.reshape(-1, 3)) @ out.T

        peer_s = _time(peer, frame)
        library_s = _time(library, frame)
        batch_s = _time(batch, frame)
        numpy_s = _time(numpy_path, frame, repeats=1)
        kind = processor.kind + (" (exact)" if processor.kind == "matrix" else
                                 f" (baked, bake error max {processor.bake_error.max:.3f})")
        print(f"{model} {kind} -> {SPACE}, 3840x2160 float frame:")
        print(f"  library apply: ours {library_s:.3f} s, peer {peer_s:.3f} s, ratio {peer_s / library_s:.2f}")
        print(f"  batch colour step: ours {batch_s:.3f} s, peer {peer_s:.3f} s, ratio {peer_s / batch_s:.2f}")
        print(f"  numpy path (before): {numpy_s:.3f} s, {numpy_s / library_s:.1f}x the library apply")
        sub = frame.reshape(-1, 3)[::97]
        got = processor.apply(sub).astype(np.float64) @ np.linalg.inv(out).T
        check = delta_E(got, fit.apply_codes(sub), fit.target_white_XYZ)
        print(f"  OCIO vs numpy on the frame: CIEDE2000 max {check.max():.3f}, mean {check.mean():.4f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
