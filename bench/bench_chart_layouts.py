"""Benchmark: every chart layout crews carry, rendered in hard conditions — camcal beside cv2.mcc and colour-checker-detection.

Inputs, the same for every detector: 108 raw captures rendered by
tests/colour/chart/chart_renders.py (camcal's synthesiser with a pinhole
camera, not Blender): the ColorChecker Classic, Passport (opened flat, both
pages in view), Mini, Nano, Digital SG (140 patches) and IT8.7/2 (288
patches, its CGATS reference file written beside it), each under six
conditions — tilted 45 degrees, 5 % and 60 % of the frame's area, turned
180 degrees, seen in a mirror, 3 stops under — three seeds each (the camera
alternating: Nikon 5100 under D65, Sigma SD Merrill under A); 14-bit RGGB
DNGs with shot and read noise, read as camcal reads them (half-size linear
camera RGB). Every detector sees the same 8-bit view
(:func:`camcal.colour.chart.find.detection_view`).

Counted as found "in order": every patch centre within a quarter of the
patch pitch of the truth in chart order (the reference data's order, as
the chart is seen from its front), and, for camcal, the mirror reported
right. camcal is given the chart type (``colour fit --chart-type``); "camcal
auto" is given the candidate references (the IT8's CGATS file, the Digital
SG's, the 24-patch ColorChecker's) and must pick the right one.
cv2.mcc (OpenCV contrib; ``MCC24`` for the 24-patch charts, ``SG140`` for the
Digital SG, no IT8.7/2 type) is counted in order and "located" (its centres
right in any of the grid's turns and mirror images: its order is its own).
colour-checker-detection (PyPI ``colour-checker-detection``, its
segmentation detector with its classic, Nano and SG settings; no IT8.7/2)
returns swatch colours, not centres: found in order when its colours, in its
order, agree with the true patch colours as camcal's orientation check asks
(:func:`camcal.colour.chart.find.colour_score` >= 1.5 and log luminances
correlated above 0.95), located when they do in any turn or mirror image. It
needs opencv < 5 by its metadata, so it is not a camcal dependency; install
it beside camcal without its dependencies to run it (``pip install --no-deps
--target DIR colour-checker-detection`` and ``PYTHONPATH=DIR``); without it
its column says "not installed".

Run: ``.venv/bin/python bench/bench_chart_layouts.py [SEEDS]`` (default 3).
The last line follows the project's form ``name: ours X, peer Y, ratio Y/X``.
"""

from __future__ import annotations

import sys
import tempfile
import time
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "tests" / "colour" / "chart"))

from chart_renders import CONDITIONS, LAYOUT_ORDER, found_in_order, render_case  # noqa: E402

from camcal.base.errors import CamcalError  # noqa: E402
from camcal.colour.chart.detect import patches_from_image  # noqa: E402
from camcal.colour.chart.find import MIN_COLOUR_SCORE, colour_score, detection_view  # noqa: E402
from camcal.colour.chart.layouts import chart_layout  # noqa: E402
from camcal.colour.chart.reference import reference_chart  # noqa: E402
from camcal.io.raw import read_raw  # noqa: E402

CCD_SETTINGS = {"classic": "CLASSIC", "passport": "CLASSIC", "mini": "CLASSIC", "nano": "NANO", "digital-sg": "SG"}


def _grid_orders(rows: int, columns: int) -> list[np.ndarray]:
    """Index permutations of a ``rows x columns`` grid: its turns and mirror images that keep its shape."""
    grid = np.arange(rows * columns).reshape(rows, columns)
    orders = [grid, grid[::-1, ::-1], grid[:, ::-1], grid[::-1, :]]
    if rows == columns:
        orders += [grid.T, grid.T[::-1, ::-1], grid.T[:, ::-1], grid.T[::-1, :]]
    return [o.ravel() for o in orders]


def _mcc(view: np.ndarray, layout: str):
    """cv2.mcc's patch centres in its order, or None."""
    import cv2

    kind = {"24": cv2.mcc.MCC24, "digital-sg": cv2.mcc.SG140}.get(chart_layout(layout).family)
    if kind is None:
        return None
    detector = cv2.mcc.CCheckerDetector_create()
    bgr = np.ascontiguousarray(view[:, :, ::-1])
    if hasattr(detector, "setColorChartType"):
        detector.setColorChartType(kind)
        found = detector.process(bgr, 1)
    else:
        found = detector.process(bgr, kind, 1)
    if not found:
        return np.zeros((0, 2))
    quads = np.asarray(detector.getBestColorChecker().getColorCharts(), dtype=np.float64).reshape(-1, 4, 2)
    return quads.mean(axis=1)


def _ccd(view: np.ndarray, layout: str):
    """colour-checker-detection's swatch colours (list of arrays), None when not installed or not supported."""
    try:
        import colour_checker_detection as ccd
    except ImportError:
        return None
    if layout not in CCD_SETTINGS:
        return None
    settings = getattr(ccd, f"SETTINGS_SEGMENTATION_COLORCHECKER_{CCD_SETTINGS[layout]}")
    try:
        return list(ccd.detect_colour_checkers_segmentation(view.astype(np.float32) / 255.0,
                                                            apply_cctf_decoding=True, **settings))
    except Exception:  # noqa: BLE001 - a peer's failure is a miss
        return []


def _corr(a, b):
    a, b = a - a.mean(), b - b.mean()
    return float((a * b).sum() / np.sqrt((a * a).sum() * (b * b).sum()))


def _colours_agree(colours: np.ndarray, truth: np.ndarray) -> bool:
    lum = lambda x: np.log(np.maximum(x.mean(axis=1), 1e-4))  # noqa: E731
    return colour_score(colours, truth) >= MIN_COLOUR_SCORE and _corr(lum(colours), lum(truth)) > 0.95


COLUMNS = ("camcal", "camcal auto", "cv2.mcc in order", "cv2.mcc located", "ccd in order", "ccd located")


class Tally:
    """Found / tried per column: in total, per layout and per (layout, condition); camcal's centre errors and every
    detector's seconds. :meth:`score` runs the three detectors on one capture, :meth:`print_summary` the tables."""

    def __init__(self) -> None:
        self.totals = {c: [0, 0] for c in COLUMNS}
        self.per_layout = {layout: {c: [0, 0] for c in COLUMNS} for layout in LAYOUT_ORDER}
        self.errors: list[float] = []
        self.seconds = {"camcal": 0.0, "cv2.mcc": 0.0, "ccd": 0.0}
        self.ccd_installed = True
        self.general = {"digital-sg": reference_chart("sg", "D50"), "24": reference_chart("cc24", "D50")}

    def score(self, render) -> dict[str, bool]:
        """camcal (given the type, and auto), cv2.mcc and colour-checker-detection on one capture (a chart_renders
        ``Render``: its DNG and truth); adds to the tallies and returns ``{column: found}``."""
        layout = render.layout
        chart = chart_layout(layout)
        image = read_raw(render.path).RGB
        view = detection_view(image, linear=True)
        n_main = chart.rows * chart.columns
        truth_main = render.centres[:n_main]
        result = {}
        t = time.perf_counter()
        try:
            found = patches_from_image(image, render.reference, linear=True)
            ok, err = found_in_order(found.detection.patch_centres(), render.centres)
            result["camcal"] = ok and found.detection.mirrored == render.mirrored
            if result["camcal"]:
                self.errors.append(err)
        except CamcalError:
            result["camcal"] = False
        self.seconds["camcal"] += time.perf_counter() - t
        candidates = ([render.reference] if layout == "it8" else []) + [self.general["digital-sg"], self.general["24"]]
        try:
            found = patches_from_image(image, candidates, linear=True)
            result["camcal auto"] = (chart_layout(found.reference.layout).family == chart.family
                                     and found_in_order(found.detection.patch_centres(), render.centres)[0])
        except CamcalError:
            result["camcal auto"] = False
        t = time.perf_counter()
        centres = _mcc(view, layout)
        self.seconds["cv2.mcc"] += time.perf_counter() - t
        if centres is not None:
            right_size = len(centres) == n_main
            result["cv2.mcc in order"] = right_size and found_in_order(centres, truth_main)[0]
            result["cv2.mcc located"] = right_size and any(
                found_in_order(centres[np.argsort(order)], truth_main)[0]
                for order in _grid_orders(chart.rows, chart.columns))
        t = time.perf_counter()
        swatches = _ccd(view, layout)
        self.seconds["ccd"] += time.perf_counter() - t
        if swatches is None and layout in CCD_SETTINGS:
            self.ccd_installed = False
        if swatches is not None:
            truth_RGB = render.RGB[:n_main]
            good = [np.asarray(s, float) for s in swatches if len(s) == n_main]
            result["ccd in order"] = any(_colours_agree(s, truth_RGB) for s in good)
            result["ccd located"] = any(_colours_agree(s[np.argsort(order)], truth_RGB) for s in good
                                        for order in _grid_orders(chart.rows, chart.columns))
        for column, value in result.items():
            for table in (self.totals, self.per_layout[layout]):
                table[column][0] += bool(value)
                table[column][1] += 1
        return result

    @staticmethod
    def header() -> str:
        return f"{'layout':11s} {'condition':20s} " + " | ".join(f"{c:>16s}" for c in COLUMNS)

    @staticmethod
    def row(layout: str, condition: str, counts: dict) -> str:
        return f"{layout:11s} {condition:20s} " + " | ".join(
            f"{counts[c][0]:>11d} / {counts[c][1]:<2d}" if counts[c][1] else f"{'n/a':>16s}" for c in COLUMNS)

    def print_summary(self) -> None:
        """Per layout, per column, the worst centre error and seconds, and the project's last line."""
        print()
        for layout in LAYOUT_ORDER:
            print(self.row(layout, "all", self.per_layout[layout]))
        n = self.totals["camcal"][1]
        print()
        for column in COLUMNS:
            done, tried = self.totals[column]
            if column.startswith("ccd") and not self.ccd_installed:
                print(f"{column}: not installed")
                continue
            share = f" ({100.0 * done / tried:.1f} %)" if tried else ""
            print(f"{column}: found {done} / {tried}{share}"
                  + (" (layouts it has no type for left out)" if tried < n else ""))
        print(f"camcal worst centre error when found: {max(self.errors, default=float('nan')):.2f} px (half-size "
              f"pixels); seconds per image: camcal {self.seconds['camcal'] / n:.2f}, "
              f"cv2.mcc {self.seconds['cv2.mcc'] / n:.2f}, colour-checker-detection {self.seconds['ccd'] / n:.2f}")
        peer = max(self.totals["cv2.mcc in order"][0], self.totals["ccd in order"][0] if self.ccd_installed else 0)
        print(f"charts found in order: ours {self.totals['camcal'][0]}, peer {peer}, "
              f"ratio {peer / max(self.totals['camcal'][0], 1):.3f}")


def main() -> None:
    warnings.filterwarnings("ignore")
    seeds = int(sys.argv[1]) if len(sys.argv) > 1 else 3
    tmp = Path(tempfile.mkdtemp(prefix="bench_chart_layouts_"))
    tally, cameras = Tally(), {}
    print(tally.header(), flush=True)
    for layout in LAYOUT_ORDER:
        for condition in CONDITIONS:
            counts = {c: [0, 0] for c in COLUMNS}
            for seed in range(seeds):
                for column, value in tally.score(render_case(tmp, layout, condition, seed, cameras)).items():
                    counts[column][0] += bool(value)
                    counts[column][1] += 1
            print(tally.row(layout, condition, counts), flush=True)
    tally.print_summary()


if __name__ == "__main__":
    main()
