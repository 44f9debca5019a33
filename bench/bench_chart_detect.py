"""Benchmark: which detector finds more ColorCheckers on raw data — camcal's segmentation, cv2.mcc, colour-checker-detection.

Inputs, the same for every detector: raw captures synthesised from measured
sensitivities (tests/colour/chart/raw_chart_scenes.py: Nikon 5100 under D65,
Sigma SDMerrill under A; the classic chart and a ColorChecker Passport opened
flat; 0, 3.5 and 5 stops under; 14-bit RGGB DNGs with shot and read noise;
three seeds each: 36 files), read as camcal reads them (half-size linear
camera RGB), and the real sRGB photo of ../shared/data/colorchecker_photo
when present. Every detector sees the same 8-bit view
(:func:`camcal.colour.chart.find.detection_view`: each channel over its 99th
percentile, sRGB-encoded).

A chart counts as found when every patch centre is within a quarter of the
patch pitch of the truth, in chart order (the sampled square reaches a
quarter of the pitch from the centre). cv2.mcc is counted as it answers
("cv2.mcc as is") and with camcal's check of its patch order by colour
("cv2.mcc oriented", what ``colour fit`` uses). colour-checker-detection
(PyPI ``colour-checker-detection``; its segmentation detector
``detect_colour_checkers_segmentation``) returns its swatch colours, not
centres: it counts as found when its 24 colours, in its order, agree with
the true patch colours as camcal's orientation check asks
(:func:`camcal.colour.chart.find.colour_score` >= 1.5) and their log
luminances correlate above 0.95. It needs opencv < 5 by its metadata, so it
is not a camcal dependency; install it beside camcal without its
dependencies to run it (``pip install --no-deps --target DIR
colour-checker-detection`` and ``PYTHONPATH=DIR``); without it its column
says "not installed".

Run: ``.venv/bin/python bench/bench_chart_detect.py``. The last line follows the
project's form ``name: ours X, peer Y, ratio Y/X``.
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

from raw_chart_scenes import write_raw_chart  # noqa: E402

from camcal.base.errors import CamcalError  # noqa: E402
from camcal.colour.chart.detect import detect_chart, reference_linear_RGB  # noqa: E402
from camcal.colour.chart.find import MIN_COLOUR_SCORE, colour_score, detection_view  # noqa: E402
from camcal.colour.chart.reference import reference_chart  # noqa: E402
from camcal.colour.spectral.simulate import SimulatedCamera  # noqa: E402
from camcal.io.raw import read_raw  # noqa: E402


def _ccd(view: np.ndarray):
    """colour-checker-detection's swatch colours (list of (24, 3)) on the view, or None when not installed."""
    try:
        from colour_checker_detection import detect_colour_checkers_segmentation
    except ImportError:
        return None
    try:
        return list(detect_colour_checkers_segmentation(view.astype(np.float32) / 255.0, apply_cctf_decoding=True))
    except Exception:  # noqa: BLE001 - a peer's failure is a miss
        return []


def _corr(a, b):
    a, b = a - a.mean(), b - b.mean()
    return float((a * b).sum() / np.sqrt((a * a).sum() * (b * b).sum()))


def main() -> None:
    warnings.filterwarnings("ignore")
    cases = []
    tmp = Path(tempfile.mkdtemp(prefix="bench_chart_detect_"))
    for camera_name, illuminant in (("Nikon 5100 (NPL)", "D65"), ("Sigma SDMerill (NPL)", "A")):
        camera = SimulatedCamera.from_colour(camera_name, illuminant)
        for layout in ("classic", "passport"):
            for stops in (0.0, 3.5, 5.0):
                for seed in range(3):
                    path = tmp / f"{camera_name.split()[0]}_{layout}_{stops}_{seed}.dng"
                    chart = write_raw_chart(path, camera, layout=layout, stops_under=stops, seed=seed)
                    image = read_raw(path).RGB
                    cases.append((f"{camera_name.split()[0]} {layout} {stops:g} stops under", image, True,
                                  chart.centres, chart.RGB))
    reference = reference_linear_RGB(reference_chart("babel", "D65"))
    photo = ROOT.parent / "shared" / "data" / "colorchecker_photo" / "img-colorchecker.jpg"
    if photo.is_file():
        from camcal.io.colourimage import read_image

        cases.append(("real sRGB photo (truth: camcal's segmentation and cv2.mcc agree within 0.15 pitch)",
                      read_image(photo), False, None, None))
    columns = ("segmentation", "cv2.mcc oriented", "cv2.mcc as is", "colour-checker-detection")
    found = {c: 0 for c in columns}
    errors = {c: [] for c in columns}
    seconds = {c: 0.0 for c in columns}
    ccd_installed = True
    for label, image, linear, truth, truth_RGB in cases:
        view = detection_view(image, linear=linear)
        row = []
        for column in columns:
            t = time.perf_counter()
            ok, err = False, np.nan
            if column == "colour-checker-detection":
                colours = _ccd(view)
                seconds[column] += time.perf_counter() - t
                if colours is None:
                    ccd_installed = False
                    row.append("-")
                    continue
                target = truth_RGB if truth_RGB is not None else reference
                ok = any(len(c) == 24 and colour_score(np.asarray(c, float), target) >= MIN_COLOUR_SCORE
                         and _corr(np.log(np.maximum(np.asarray(c, float).mean(axis=1), 1e-4)),
                                   np.log(np.maximum(target.mean(axis=1), 1e-4))) > 0.95 for c in colours)
            else:
                try:
                    if column == "cv2.mcc as is":
                        detection = detect_chart(image, linear=linear, detector="cv2.mcc")
                    else:
                        detection = detect_chart(image, linear=linear, reference_RGB=reference,
                                                 detector=column.split()[0])
                    centres = detection.patch_centres()
                    if truth is None:
                        other = detect_chart(image, linear=linear, reference_RGB=reference,
                                             detector="cv2.mcc" if column == "segmentation" else "segmentation")
                        truth_here = other.patch_centres()
                    else:
                        truth_here = truth
                    pitch = np.median(np.linalg.norm(np.diff(truth_here.reshape(4, 6, 2), axis=1), axis=2))
                    err = float(np.abs(centres - truth_here).max())
                    ok = err < (0.15 if truth is None else 0.25) * pitch
                except CamcalError:
                    pass
                seconds[column] += time.perf_counter() - t
            found[column] += ok
            if ok and np.isfinite(err):
                errors[column].append(err)
            row.append(("yes" if ok else "no") + ("" if not np.isfinite(err) or not ok else f" ({err:.1f} px)"))
        print(f"{label:70s} " + " | ".join(f"{c}: {r}" for c, r in zip(columns, row)), flush=True)
    n = len(cases)
    print()
    for column in columns:
        if column == "colour-checker-detection" and not ccd_installed:
            print(f"{column}: not installed")
            continue
        worst = f", worst centre error {max(errors[column]):.2f} px" if errors[column] else ""
        print(f"{column}: found {found[column]} / {n}{worst}, {seconds[column] / n:.2f} s per image")
    peer = max(found["cv2.mcc oriented"], found["colour-checker-detection"] if ccd_installed else 0)
    print(f"charts found: ours {found['segmentation']}, peer {peer}, ratio {peer / max(found['segmentation'], 1):.3f}")


if __name__ == "__main__":
    main()
