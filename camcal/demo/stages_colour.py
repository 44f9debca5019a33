"""Colour stages of the demo: colour fit, colour match, colour export."""

from __future__ import annotations

import html
import os
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

from camcal.base.extras import require
from camcal.demo.core import (
    COLOUR_EXPORTS_SECTION, DemoContext, DemoRow, ReportSection, StageResult, command_line, run_cli,
)
from camcal.demo.report import img_tag

__all__ = [
    "stage_colour_export",
    "stage_colour_fit",
    "stage_colour_match",
]


# Where each row's tolerance comes from, as the demo prints it.
_RENDER_NOISE = "sensor noise of the colour fit tests (0.2 %)"
_PEER_COLOUR_SCIENCE = "colour-science's best method on the same patches"
_MATCH_TEST = "colour match test (tests/pipelines/test_colour_match_stereo.py)"
_OWN_ERRORS_SUM = "the sum of both cameras' own errors"
_EXPORT_TEST = "colour export tests (tests/colour/export/)"


#: colour-science's methods compared with ``colour fit`` (the best is an oracle
#: pick, on the independent set itself).
_COLOUR_SCIENCE = (
    [("Cheung 2004", {"terms": t}) for t in (3, 5, 7, 8, 10, 11, 14, 16, 17, 19, 20, 22)]
    + [("Finlayson 2015", {"degree": d}) for d in (1, 2, 3)]
    + [("Vandermonde", {"degree": d}) for d in (1, 2, 3)]
)


# -- stage: colour fit -------------------------------------------------------------------------


def _colour_science_best(train, test, white) -> tuple[float, str]:
    """colour-science's best ``matrix_colour_correction`` on the independent set (oracle pick)."""
    require("colour")
    from colour.characterisation import apply_matrix_colour_correction, matrix_colour_correction  # noqa: PLC0415

    from camcal.colour.difference import delta_E  # noqa: PLC0415

    best = []
    for method, kw in _COLOUR_SCIENCE:
        M = matrix_colour_correction(train.RGB, train.XYZ, method=method, **kw)
        pred = apply_matrix_colour_correction(test.RGB, M, method=method, **kw)
        label = f"{method} " + ", ".join(f"{k}={v}" for k, v in kw.items())
        best.append((float(np.mean(delta_E(pred, test.XYZ, white))), label))
    return min(best)


def _colour_fit_argv(ctx: DemoContext, name: str, model: str, out: Path) -> list[str]:
    """``camcal colour fit`` of camera ``name``'s rendered chart, judged on its independent patches."""
    return ["colour", "fit", "--chart", str(ctx.need("chart_images", "colour fit")[name]),
            "--reference", "ISO 17321-1", "--illuminant", ctx.truth.illuminant, "--linearise", "none",
            "--model", model, "--test-patches", str(_independent_csv(ctx, name)), "--camera-name", name, "--out", str(out)]


def _independent_csv(ctx: DemoContext, name: str) -> Path:
    """Where the colour fit stage writes camera ``name``'s independent patches (the 190 reflectances)."""
    return ctx.path("colour", f"{name}_independent.csv")


def stage_colour_fit(ctx: DemoContext) -> StageResult:
    from camcal.pipelines.colour import patches_from_chart  # noqa: PLC0415
    from camcal.io.colourfile import load_fit  # noqa: PLC0415
    from camcal.colour.chart.patches import PatchSet  # noqa: PLC0415
    from camcal.io.patches import read_patch_csv, write_patch_csv  # noqa: PLC0415

    stage = "colour fit"
    truth = ctx.truth
    charts = ctx.need("chart_images", stage)
    albedos = ctx.need("chart_truth", stage)
    rows, outputs, body = [], [], ""
    fits, detected, tests = {}, {}, {}
    for name, chart in charts.items():
        chart_rgb, test_rgb, test_xyz = albedos[name]
        test_csv = _independent_csv(ctx, name)
        write_patch_csv(test_csv, PatchSet(tuple(f"rawtoaces{i:03d}" for i in range(len(test_rgb))), test_rgb, test_xyz))
        tests[name] = test_csv
        fit_path = ctx.path("colour", f"{name}.colour.json")
        report_dir = ctx.out_dir / "colour" / name
        argv = _colour_fit_argv(ctx, name, ctx.config.colour_model, fit_path) + ["--report", str(report_dir)]
        run_cli(argv, stage)
        fits[name] = fit_path
        found = patches_from_chart(chart, "ISO 17321-1", illuminant=truth.illuminant)
        detected[name] = found.patches
        kept = [found.reference.patch_names.index(n) for n in found.patches.names]
        relative = np.abs(found.patches.RGB / chart_rgb[kept] - 1.0)
        rows.append(DemoRow(stage, f"{name} chart RGB vs simulated sensor (worst)", 0.0, 100 * float(relative.max()),
                            100 * float(relative.max()), 0.2, "%", _RENDER_NOISE))
        test = read_patch_csv(test_csv)
        peer, label = _colour_science_best(found.patches, test, found.reference.white_XYZ)
        ours = float(load_fit(fit_path).evaluation["test"]["mean"])
        rows.append(DemoRow(stage, f"{name} independent mean dE2000 (vs colour-science)", 0.0, ours, ours, peer,
                            "dE00", _PEER_COLOUR_SCIENCE))
        outputs.append((f"{name} colour fit ({name}.colour.json)", fit_path))
        summary = (report_dir / "summary.txt").read_text()
        body += (f"<h3>{html.escape(name)}: {html.escape(truth.sensors[name])} under {truth.illuminant}</h3>"
                 f"<pre>{html.escape(command_line(argv, ctx))}</pre><pre>{html.escape(summary)}</pre>"
                 f"<p>colour-science's best on the same patches (picked on the independent set itself): "
                 f"{html.escape(label)}, mean CIEDE2000 {peer:.3f}.</p>"
                 f"{img_tag(ctx, report_dir / 'train' / 'swatches.png', width=480)}"
                 f"{img_tag(ctx, report_dir / 'test' / 'delta_E_histogram.png', width=420)}"
                 f"{img_tag(ctx, report_dir / 'test' / 'ab_errors.png', width=420)}")
    ctx.artifacts["colour_fits"] = fits
    ctx.artifacts["independent_patches"] = tests
    # the patches both cameras' charts gave (what the chart route of ``colour match`` reads)
    common = [n for n in detected["left"].names if all(n in d.names for d in detected.values())]
    chart_csvs = {}
    for name, patches in detected.items():
        chart_csvs[name] = ctx.path("colour", f"{name}_chart.csv")
        write_patch_csv(chart_csvs[name], patches.subset([patches.names.index(n) for n in common]))
    ctx.artifacts["chart_patches"] = chart_csvs
    return StageResult(tuple(rows), tuple(outputs), (ReportSection("Colour characterisation", body, "colour-fit"),))


# -- stage: colour match --------------------------------------------------------------------------


def stage_colour_match(ctx: DemoContext) -> StageResult:
    from camcal.colour.difference import delta_E  # noqa: PLC0415
    from camcal.io.colourfile import load_fit  # noqa: PLC0415
    from camcal.io.colourfile import load_match  # noqa: PLC0415

    stage = "colour match"
    fits = ctx.need("colour_fits", stage)
    images = ctx.need("match_images", stage)
    N = ctx.need("match_truth", stage)
    albedos = ctx.need("chart_truth", stage)
    board_rig = ctx.need("board_rig", stage)
    rows, outputs = [], []
    # image route: the stereo pair of the match scene, rectified with the board calibration
    image_match = ctx.path("colour", "match_right_to_left.colour.json")
    report_dir = ctx.out_dir / "colour" / "match"
    argv = ["colour", "match", str(board_rig), "--images", f"left={images['left']}", f"right={images['right']}",
            "--fits", f"left={fits['left']}", f"right={fits['right']}", "--model", "matrix3x3",
            "--out", str(image_match), "--report", str(report_dir)]
    run_cli(argv, stage)
    match = load_match(image_match)
    left_fit = load_fit(fits["left"])
    # held-out colours: the 190 independent reflectances as the right camera sees them
    right_rgb = albedos["right"][1]
    dE = delta_E(left_fit.apply(match.apply(right_rgb)), left_fit.apply(right_rgb @ N.T), left_fit.target_white_XYZ)
    rows.append(DemoRow(stage, "match (image route) vs true N, mean dE00", 0.0, float(dE.mean()),
                        float(dE.mean()), 0.5, "dE00", _MATCH_TEST))
    outputs.append(("camera match right -> left, image route (match_right_to_left.colour.json)", image_match))
    ctx.artifacts["colour_match"] = image_match
    # chart route: both characterisations on the same chart, judged on the independent set
    chart_match = ctx.path("colour", "match_chart.colour.json")
    patches = ctx.need("chart_patches", stage)
    tests = ctx.need("independent_patches", stage)
    chart_argv = ["colour", "match", "--fits", f"left={fits['left']}", f"right={fits['right']}",
                  "--patches", f"left={patches['left']}", f"right={patches['right']}",
                  "--test-patches", f"left={tests['left']}", f"right={tests['right']}",
                  "--model", "root-polynomial:2", "--out", str(chart_match)]
    run_cli(chart_argv, stage)
    chart = load_match(chart_match)
    own = sum(float(load_fit(fits[n]).evaluation["test"]["mean"]) for n in ("left", "right"))
    after = float(chart.evaluation["test"]["mean"])
    rows.append(DemoRow(stage, "match (chart route) camera-to-camera dE00", 0.0, after, after, own,
                        "dE00", _OWN_ERRORS_SUM))
    outputs.append(("camera match right -> left, chart route (match_chart.colour.json)", chart_match))
    before = chart.evaluation["before"]["mean"]
    pictures = [report_dir / f for f in ("target.png", "source_before.png", "source_after.png",
                                         "delta_E_before.png", "delta_E_after.png", "valid.png")]
    body = (f"<pre>{html.escape(command_line(argv, ctx))}</pre><pre>{html.escape(match.summary())}</pre>"
            f"<p>Image route: the match scene rendered by both cameras, rectified with the board calibration, "
            f"SGBM correspondences with a left-right check, robust fit (LMedS + IRLS). Judged against the true "
            f"matrix <i>N</i> on colours the fit never saw (the right sensor's RGB of the 190 independent "
            f"reflectances), in CIEDE2000 through the left camera's characterisation: mean {dE.mean():.3f}, "
            f"max {dE.max():.3f}.</p>"
            + "".join(img_tag(ctx, p, width=320) for p in pictures if p.is_file())
            + f"<pre>{html.escape(command_line(chart_argv, ctx))}</pre><pre>{html.escape(chart.summary())}</pre>"
            f"<p>Chart route: both cameras to XYZ through their characterisations; camera-to-camera CIEDE2000 on "
            f"the independent set {before:.2f} before, {after:.2f} after the match (the tolerance is "
            f"the sum of the two cameras' own errors, {own:.2f}).</p>")
    return StageResult(tuple(rows), tuple(outputs), (ReportSection("Colour match between the cameras", body, "colour-match"),))


# -- stage: colour export -------------------------------------------------------------------------

#: OCIO's XYZ space in camcal's base config (and in the ACES studio config).
_OCIO_XYZ_D65 = "CIE XYZ-D65 - Scene-referred"


def _ocio_apply(processor, RGB: NDArray) -> NDArray[np.float64]:
    """OCIO's CPU processor without its fast approximations (lossless optimisation)."""
    ocio = require("PyOpenColorIO")

    from camcal.colour.bake.transforms import apply_cpu  # noqa: PLC0415

    return apply_cpu(processor.getOptimizedCPUProcessor(ocio.OPTIMIZATION_LOSSLESS), RGB)


def stage_colour_export(ctx: DemoContext) -> StageResult:
    ocio = require("PyOpenColorIO")

    from camcal.colour.difference import delta_E  # noqa: PLC0415
    from camcal.colour.export.icc import D50_XYZ  # noqa: PLC0415
    from camcal.colour.export.ocio_config import colour_space_name  # noqa: PLC0415
    from camcal.colour.export.ocio_fit import look_name  # noqa: PLC0415
    from camcal.io.colourfile import load_fit  # noqa: PLC0415
    from camcal.colour.export.lcms import lcms_to_XYZ, load_lcms  # noqa: PLC0415
    from camcal.io.colourfile import load_match  # noqa: PLC0415
    from camcal.io.patches import read_patch_csv  # noqa: PLC0415
    from camcal.colour.spectral.data import adapt_XYZ, illuminant_white_XYZ  # noqa: PLC0415

    stage = "colour export"
    # auto only picks fits the exporters take (camcal.colour.fit.select): no refit is ever needed here
    fits, commands = dict(ctx.need("colour_fits", stage)), []
    samples = {name: np.vstack([read_patch_csv(ctx.need("chart_patches", stage)[name]).RGB,
                                read_patch_csv(ctx.need("independent_patches", stage)[name]).RGB])
               for name in fits}
    match_path = ctx.artifacts.get("colour_match")
    ocio_dir = ctx.out_dir / "ocio"
    argv = ["colour", "export", *map(str, fits.values()), *([str(match_path)] if match_path else []),
            "--ocio", str(ocio_dir), "--base", "camcal"]
    run_cli(argv, stage)
    config = ocio.Config.CreateFromFile(str(ocio_dir / "config.ocio"))
    D65 = illuminant_white_XYZ("D65")
    lcms = load_lcms()
    rows, outputs = [], [("OCIO config (config.ocio)", ocio_dir / "config.ocio")]
    commands.append(argv)
    for name, path in fits.items():
        fit = load_fit(path)
        codes = samples[name]
        expected = fit.apply_codes(codes)
        got = _ocio_apply(config.getProcessor(colour_space_name(name), _OCIO_XYZ_D65), codes)
        truth = adapt_XYZ(expected, fit.target_white_XYZ, D65, "Bradford")
        what = f"{name} OCIO space vs fit"
        if fit.model.kind == "matrix3x3":
            err = float(np.abs(got - truth).max())
            rows.append(DemoRow(stage, what + ", worst |XYZ|", 0.0, err, err, 1e-5, "Y=1", _EXPORT_TEST))
        else:
            err = float(delta_E(got, truth, D65).max())
            rows.append(DemoRow(stage, what + ", worst dE00", 0.0, err, err, 0.2, "dE00", _EXPORT_TEST))
        icc = ctx.path("icc", f"{name}.icc")
        icc_argv = ["colour", "export", str(path), "--icc", str(icc)]
        run_cli(icc_argv, stage)
        commands.append(icc_argv)
        outputs.append((f"ICC v4 camera profile, {name} ({name}.icc)", icc))
        err = float("nan")
        if lcms is not None:
            D50 = adapt_XYZ(expected, fit.target_white_XYZ, D50_XYZ, "Bradford")
            keep = D50[:, 1] > 0.01  # CIEDE2000 of near-black says nothing
            err = float(delta_E(lcms_to_XYZ(lcms, icc.read_bytes(), codes)[keep], D50[keep], D50_XYZ).max())
        rows.append(DemoRow(stage, f"{name} ICC (LittleCMS) vs fit, worst dE00", 0.0, err, err, 0.2,
                            "dE00", _EXPORT_TEST))
    if match_path:
        match = load_match(match_path)
        look = look_name(match.source, match.target)
        data = config.getRoleColorSpace(ocio.ROLE_DATA)
        rgb = samples[match.source]
        got = _ocio_apply(config.getProcessor(ocio.LookTransform(src=data, dst=data, looks=look)), rgb)
        err = float(np.abs(got - match.apply(rgb)).max())
        rows.append(DemoRow(stage, "match Look vs match file, worst |RGB|", 0.0, err, err, 1e-5, "RGB",
                            _EXPORT_TEST))
    clfs = sorted(ocio_dir.rglob("*.clf"))
    outputs += [(f"baked transform ({p.name})", p) for p in clfs]
    spaces = [colour_space_name(name) for name in fits]
    body = ("".join(f"<pre>{html.escape(command_line(a, ctx))}</pre>" for a in commands)
            + "<p>The config <a href=\"ocio/config.ocio\">ocio/config.ocio</a> (camcal's base: ACES2065-1 "
              "reference, the roles Blender needs) gains the input spaces "
            + ", ".join(f"<code>{html.escape(n)}</code>" for n in spaces)
            + (f" and the Look <code>{html.escape(look_name(match.source, match.target))}</code> (right camera "
               f"matched to the left, on linear camera values)" if match_path else "")
            + ". Point Blender at it with <code>OCIO=ocio/config.ocio blender</code>. Checked here with OCIO's "
              "own CPU processor against each fit on the chart and independent patches, and each ICC profile "
              "(class scnr, v4) through LittleCMS.</p><ul>"
            + "".join(f'<li><a href="{html.escape(os.path.relpath(p, ctx.out_dir))}">'
                      f"{html.escape(os.path.relpath(p, ctx.out_dir))}</a></li>"
                      for p in [ocio_dir / "config.ocio", *clfs, *(ctx.out_dir / "icc" / f"{n}.icc" for n in fits)])
            + "</ul>")
    return StageResult(tuple(rows), tuple(outputs),
                       (ReportSection("Colour exports: OCIO config and ICC profiles", body, COLOUR_EXPORTS_SECTION),))
