"""Every chart layout rendered in Blender (chart_blender.py), made camera raw, and found with its patch values.

The truth is the scene's: the patch centres projected by the camera Cycles
rendered with, the mirror applied to the print, the IT8.7/2's CGATS file,
and each patch's value: its albedo (camera RGB) times the lamps' shading at
its centre (:func:`chart_blender.shading`), checked against the rendered
EXR before the raw step. The slow test renders one capture of each layout,
the six conditions shared among them; its fast siblings are the same
detection and patch checks on captures of camcal's own synthesiser
(test_chart_layouts.py: ``test_a_rendered_chart_is_found_with_every_patch_in_order``:
found, every patch in order, the mirror, the patches' colours).
"""

import warnings

import numpy as np
import pytest
from chart_blender import blender_case, raw_capture, render_cases, shading
from chart_renders import found_in_order

from camcal.colour.chart.layouts import chart_layout
from camcal.io.stmap import read_exr
from camcal.pipelines.colour import patches_from_chart

#: (layout, condition, seed): every layout once, every condition at least once, both cameras.
HANDFUL = (("classic", "perspective 45 deg", 0), ("passport", "rotated 180 deg", 1), ("mini", "3 stops under", 0),
           ("nano", "5 % of the frame", 1), ("digital-sg", "mirrored", 0), ("it8", "60 % of the frame", 1))


def _bilinear(image: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """``image`` at sub-pixel points ``xy`` (pixel (0, 0) at the top-left pixel's centre)."""
    x0, y0 = np.floor(xy).astype(int).T
    fx, fy = (xy - np.floor(xy)).T[:, :, None]
    return ((1 - fy) * ((1 - fx) * image[y0, x0] + fx * image[y0, x0 + 1])
            + fy * ((1 - fx) * image[y0 + 1, x0] + fx * image[y0 + 1, x0 + 1]))


@pytest.mark.slow
def test_charts_rendered_in_blender_are_found_with_their_patch_values(tmp_path):
    """Each layout found (its type named), every patch in order, the mirror seen, the raw patch values the render's."""
    warnings.filterwarnings("ignore")
    cameras: dict = {}
    cases = [blender_case(tmp_path, layout, condition, seed, cameras) for layout, condition, seed in HANDFUL]
    exrs = render_cases(tmp_path, cases, cameras, threads=2)
    for case, exr in zip(cases, exrs):
        render = raw_capture(tmp_path, case)
        # the render's known values: Cycles' pixel at a patch centre is the albedo times the shading formula
        rendered = _bilinear(read_exr(exr)[..., :3], render.centres)
        known = case.albedo_RGB * shading(case.centres_world, case.lamp, case.key)[:, None]
        np.testing.assert_allclose(rendered, known, rtol=0.01, err_msg=case.stem)
        found = patches_from_chart(render.path, tmp_path / f"{case.stem}.it8.txt" if case.layout == "it8" else None,
                                   chart_type=case.layout if chart_layout(case.layout).family == "24" else "auto")
        assert found.reference.layout == case.layout, case.stem
        ok, error = found_in_order(found.detection.patch_centres(), render.centres)
        assert ok, f"{case.stem}: worst patch centre {error:.1f} px from the truth"
        assert found.detection.mirrored == render.mirrored, case.stem
        # the patch values camcal reads from the raw file are the rendered ones at the capture's exposure
        sampled, truth = found.samples.RGB, render.RGB
        bright = truth.min(axis=1) > 0.02 * truth.max()
        relative = np.abs(sampled[bright] / truth[bright] - 1)
        assert np.median(relative) < 0.01 and relative.max() < 0.06, (case.stem, np.median(relative), relative.max())
        assert np.abs(sampled - truth).max() < 0.008 * truth.max(), case.stem
