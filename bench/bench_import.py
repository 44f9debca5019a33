"""``import camcal`` in a fresh interpreter: the public API loads lazily, so the import costs less than the
0.3 s budget and less than ``import numpy`` (the peer every scientific package starts with).

Prints ``import camcal: X s, import numpy: Y s, ratio Y/X`` (median of fresh processes, the bare interpreter's
start-up subtracted) and ``heavy modules loaded: []``.
"""

import statistics
import subprocess
import sys
import time

RUNS = 7
BUDGET_S = 0.3
HEAVY = ("cv2", "pycolmap", "dask", "distributed", "pxr", "scipy", "colour", "matplotlib", "PyOpenColorIO", "bpy")


def seconds(code: str) -> float:
    """Median wall time of ``python -c code`` over :data:`RUNS` fresh processes."""
    times = []
    for _ in range(RUNS):
        start = time.perf_counter()
        subprocess.run([sys.executable, "-c", code], check=True)
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def main() -> None:
    bare = seconds("pass")
    ours = seconds("import camcal") - bare
    peer = seconds("import numpy") - bare
    loaded = subprocess.run([sys.executable, "-c", f"import sys, camcal; print([m for m in {HEAVY!r} if m in "
                             "sys.modules])"], check=True, capture_output=True, text=True).stdout.strip()
    print(f"import camcal: {ours:.3f} s, import numpy: {peer:.3f} s, ratio {peer / max(ours, 1e-6):.1f} "
          f"(budget {BUDGET_S} s: {'kept' if ours < BUDGET_S else 'EXCEEDED'})")
    print(f"heavy modules loaded by import camcal: {loaded}")


if __name__ == "__main__":
    main()
