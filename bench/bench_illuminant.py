"""Benchmark: a fit for another illuminant: spectral route vs CAT02 vs Bradford (and colour-science's IDT).

Scene, for each of colour-science's two measured cameras (Nikon 5100,
Sigma SDMerill): a ColorChecker 24 (BabelColor Average spectra) captured
under D65 with 0.2 % RGB noise; the fit is to be used under illuminant A.
The camera's sensitivities are known three ways:

- ``measured``: the true curves (as from a monochromator);
- ``estimated, 1 chart``: estimated from that one D65 chart capture only;
- ``estimated, 5 lights``: estimated from the chart captured under D65, FL2,
  LED-B3, FL11 and D50 (no capture under A).

Routes (camcal.colour.fit.illuminant): ``spectral`` (fit on the 190 RAW to ACES
reflectances rendered through the sensitivities under A), ``CAT02`` and
``Bradford`` (fit on the chart under D65, white balance from the
sensitivities, von Kries adaptation of the output). camcal picks the route and its
model (``auto``: every linear-terms model for every route) by the RMS
CIEDE2000 on its own validation set (``Munsell validation``: 300 Munsell
colours, Otsu 2018 recovery) through the sensitivities.

Judged on reflectances used by no step: 300 other Munsell colours
(``Munsell held-out``), the 30 PMC patches, the 14 CIE 1995 TCS and the 15
NIST CQS 9.0 samples (359), rendered by the TRUE camera under A, CIEDE2000
against their XYZ under A. Peer: colour-science's ``matrix_idt`` (RAW to
ACES v1 method: same sensitivities, same 190 training reflectances, 3x3
in CIE 1976 Lab via ACES2065-1, converted back to XYZ under A with CAT02).

Run: ``.venv/bin/python bench/bench_illuminant.py [MODEL]`` (default ``auto``); the last lines read
``name: ours X, peer Y, ratio Y/X`` (mean CIEDE2000; peer = the best
adaptation route (CAT02/Bradford) and colour-science's IDT).
"""

from __future__ import annotations

import sys
import time
import warnings

import numpy as np

warnings.filterwarnings("ignore")

from camcal.colour.fit.characterise import white_from_name  # noqa: E402
from camcal.colour.difference import DeltaEStats, delta_E  # noqa: E402
from camcal.colour.fit.illuminant import characterise_for_illuminant, reflectance_XYZ  # noqa: E402
from camcal.colour.chart.patches import PatchSet  # noqa: E402
from camcal.colour.spectral.data import camera_sensitivities, reflectance_set  # noqa: E402
from camcal.colour.spectral.captures import Capture, estimate_from_captures  # noqa: E402
from camcal.colour.spectral.sensitivities import Sensitivities, illuminant_spd  # noqa: E402

CAMERAS = {"Nikon 5100 (NPL)": np.arange(400.0, 701.0, 10.0), "Sigma SDMerill (NPL)": np.arange(400.0, 681.0, 10.0)}
CHART_LIGHT, USE_LIGHT = "D65", "A"
NOISE = 0.002
JUDGING = ("Munsell held-out", "PMC", "CIE 1995 TCS", "NIST CQS 9.0")
SSF_LIGHTS = ("D65", "FL2", "LED-B3", "FL11", "D50")


def judging_set(true: Sensitivities) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """RGB (true camera under A), XYZ under A, white."""
    RGB, XYZ = [], []
    for name in JUDGING:
        _, X, white = reflectance_XYZ(name, USE_LIGHT)
        _, R = reflectance_set(name, true.wavelengths)
        RGB.append(true.camera_under(USE_LIGHT).RGB(R))
        XYZ.append(X)
    return np.vstack(RGB), np.vstack(XYZ), white


def chart_capture(true: Sensitivities, light: str, seed: int) -> Capture:
    names, R = reflectance_set("BabelColor Average", true.wavelengths)
    RGB = true.camera_under(light).RGB(R, noise=NOISE, seed=seed) * 0.8
    return Capture(tuple(names), R, RGB, illuminant_spd(light, true.wavelengths), light, f"cc24 under {light}")


def colour_science_idt(sens: Sensitivities, RGB: np.ndarray, white_B: np.ndarray) -> np.ndarray:
    """colour-science's matrix_idt (RAW to ACES v1) applied to RGB, returned as XYZ under A."""
    import colour

    # on the IDT's own grid, linearly interpolated and zero outside the curves' range (colour-science
    # would otherwise interpolate and extend them itself)
    from colour.characterisation.aces_it import SPECTRAL_SHAPE_RAWTOACES as shape

    grid = np.asarray(shape.wavelengths, dtype=np.float64)
    values = np.stack([np.interp(grid, sens.wavelengths, sens.values[:, c], left=0.0, right=0.0) for c in range(3)], 1)
    msds = colour.characterisation.RGB_CameraSensitivities(values, grid, labels=("red", "green", "blue"))
    M, _ = colour.matrix_idt(msds, colour.SDS_ILLUMINANTS[USE_LIGHT])
    white_rgb = sens.camera_under(USE_LIGHT).RGB_white
    ACES = (RGB / white_rgb) @ M.T
    XYZ_aces = colour.RGB_to_XYZ(ACES, colour.RGB_COLOURSPACES["ACES2065-1"], chromatic_adaptation_transform=None)
    aces_white = colour.xy_to_XYZ(colour.RGB_COLOURSPACES["ACES2065-1"].whitepoint)
    return colour.chromatic_adaptation(XYZ_aces, aces_white, white_B, method="Von Kries", transform="CAT02")


def main(model: str = "auto") -> int:
    rows = []
    print(f"chart under {CHART_LIGHT} ({NOISE:.1%} noise), fit used under {USE_LIGHT}; judged on "
          f"{' + '.join(JUDGING)} through the true camera under {USE_LIGHT}\n")
    header = f"{'camera':22s} {'sensitivities':22s} {'route':30s} {'mean':>6s} {'p95':>6s} {'max':>6s}  validation RMS"
    print(header)
    print("-" * len(header))
    for camera, wl in CAMERAS.items():
        true = Sensitivities(wl, camera_sensitivities(camera, wl)[1], camera=camera)
        RGB_J, XYZ_J, white_J = judging_set(true)
        chart = chart_capture(true, CHART_LIGHT, 1)
        _, XYZ_chart, _ = reflectance_XYZ("BabelColor Average", CHART_LIGHT)
        train = PatchSet(chart.names, chart.RGB, XYZ_chart)
        sources = {
            "measured": true,
            "estimated, 1 chart": estimate_from_captures([chart], wl, camera=camera),
            "estimated, 5 lights": estimate_from_captures(
                [chart] + [chart_capture(true, light, 10 + i) for i, light in enumerate(SSF_LIGHTS[1:])], wl,
                camera=camera),
        }
        for label, sens in sources.items():
            start = time.perf_counter()
            out = characterise_for_illuminant(train, sens, illuminant=CHART_LIGHT, for_illuminant=USE_LIGHT,
                                              model=model, camera=camera)
            seconds = time.perf_counter() - start
            judged = {}
            for route, fit in out.fits.items():
                judged[route] = DeltaEStats.from_values(delta_E(fit.apply(RGB_J), XYZ_J, white_J))
            judged["colour-science IDT"] = DeltaEStats.from_values(
                delta_E(colour_science_idt(sens, RGB_J, white_J), XYZ_J, white_J))
            validation = {s.route: s.rms for s in out.scores}
            for route, stats in judged.items():
                name = route if route not in out.fits else f"{route} ({out.fits[route].model.label})"
                mark = " <- camcal" if route == out.picked else ""
                v = f"{validation[route]:.3f}" if route in validation else "-"
                print(f"{camera:22s} {label:22s} {name:30s} {stats.mean:6.3f} {stats.p95:6.3f} {stats.max:6.3f}  "
                      f"{v:>6s}{mark}")
            best_route = min(out.fits, key=lambda r: judged[r].mean)
            rows.append((camera, label, out.picked, best_route, judged, seconds))
        print()
    print("camcal's choice vs the best route on the held-out reflectances:")
    all_best = True
    for camera, label, picked, best_route, judged, seconds in rows:
        ok = judged[picked].mean <= judged[best_route].mean + 1e-12
        all_best &= ok
        print(f"  {camera}, {label}: picked {picked} ({judged[picked].mean:.3f}), best {best_route} "
              f"({judged[best_route].mean:.3f}) -> {'best' if ok else 'NOT the best'} ({seconds:.1f} s)")
    print()
    for camera, label, picked, best_route, judged, seconds in rows:
        ours = judged[picked].mean
        cat = min(judged["CAT02"].mean, judged["Bradford"].mean)
        idt = judged["colour-science IDT"].mean
        tag = f"{camera.split()[0]} {label}"
        print(f"illuminant {tag} vs adaptation: ours {ours:.3f}, peer {cat:.3f}, ratio {cat / ours:.2f}")
        print(f"illuminant {tag} vs colour-science IDT: ours {ours:.3f}, peer {idt:.3f}, ratio {idt / ours:.2f}")
    return 0 if all_best else 1


if __name__ == "__main__":
    sys.exit(main(*sys.argv[1:2]))
