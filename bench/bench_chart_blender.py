"""Benchmark: every chart layout rendered in Blender and made camera raw — camcal beside cv2.mcc and colour-checker-detection.

Inputs, the same for every detector: 108 captures rendered by Cycles
(tests/colour/chart/chart_blender.py): the ColorChecker Classic, Passport
(opened flat, both pages), Mini, Nano, Digital SG and IT8.7/2 as textured
diffuse planes on a cluttered table, lit by a point lamp whose light falls
off across the chart and a sun as fill, each under the six conditions of
bench_chart_layouts.py — perspective 45 degrees, 5 % and 60 % of the
frame, rotated 180 degrees, mirrored, 3 stops under — three seeds each
(Nikon 5100 under D65, Sigma SD Merrill under A, alternating), the render
(camera RGB, 900 x 600) mosaicked into a 14-bit RGGB DNG with shot and read
noise by the synthesiser of the other chart benches, read as camcal reads
raw (half-size linear camera RGB). Every detector sees the same 8-bit view.

Counted as in bench_chart_layouts.py (its ``Tally``): "in order" is every
patch centre within a quarter of the patch pitch of the truth in chart
order (and, for camcal, the mirror reported right). Neither peer has an
IT8.7/2 type (cv2.mcc: ``MCC24`` and ``SG140``; colour-checker-detection:
its classic, Nano and SG settings): their IT8.7/2 rows say n/a and their
totals leave those 18 captures out. colour-checker-detection is found through ``PYTHONPATH`` as in
that bench (``pip install --no-deps --target DIR colour-checker-detection``).

Run: ``.venv/bin/python bench/bench_chart_blender.py [SEEDS] [--renders DIR]``
(default 3 seeds; ``--renders`` keeps the EXRs in DIR and renders only
those missing, so a second run re-detects without Blender). The last line
follows the project's form ``name: ours X, peer Y, ratio Y/X``.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "bench"))
sys.path.insert(0, str(ROOT / "tests" / "colour" / "chart"))

from bench_chart_layouts import COLUMNS, Tally  # noqa: E402
from chart_blender import blender_case, raw_capture, render_cases  # noqa: E402
from chart_renders import CONDITIONS, LAYOUT_ORDER  # noqa: E402


def main() -> None:
    warnings.filterwarnings("ignore")
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("seeds", nargs="?", type=int, default=3)
    parser.add_argument("--renders", type=Path, default=None)
    args = parser.parse_args()
    folder = args.renders or Path(tempfile.mkdtemp(prefix="bench_chart_blender_"))
    folder.mkdir(parents=True, exist_ok=True)
    cameras: dict = {}
    cases = [blender_case(folder, layout, condition, seed, cameras)
             for layout in LAYOUT_ORDER for condition in CONDITIONS for seed in range(args.seeds)]
    t = time.perf_counter()
    render_cases(folder, cases, cameras)
    print(f"{len(cases)} Cycles renders in {folder}: {time.perf_counter() - t:.0f} s "
          f"(0 when kept from an earlier run)", flush=True)
    tally = Tally()
    per_condition = {condition: {c: [0, 0] for c in COLUMNS} for condition in CONDITIONS}
    shares = []
    print(tally.header(), flush=True)
    for layout in LAYOUT_ORDER:
        for condition in CONDITIONS:
            counts = {c: [0, 0] for c in COLUMNS}
            for case in cases:
                if (case.layout, case.condition) != (layout, condition):
                    continue
                shares.append(case.share)
                for column, value in tally.score(raw_capture(folder, case)).items():
                    for table in (counts, per_condition[condition]):
                        table[column][0] += bool(value)
                        table[column][1] += 1
            print(tally.row(layout, condition, counts), flush=True)
    print()
    for condition in CONDITIONS:
        print(tally.row("all", condition, per_condition[condition]))
    print(f"chart's share of the frame: {100 * min(shares):.1f} % to {100 * max(shares):.1f} %")
    tally.print_summary()


if __name__ == "__main__":
    main()
