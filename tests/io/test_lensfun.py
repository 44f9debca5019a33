"""Lensfun XML export checked by Lensfun itself (lensfunpy): its correction against camcal's, in pixels.

Lensfun's correction maps each pixel of its undistorted image (a pinhole
image of focal ``F`` pixels about the lens centre, ``F`` from the entry's
``focal`` in Lensfun's own normalisation) to the source pixel in the
distorted image. camcal's for the same pixel: the pinhole ray of that pixel
projected by the camcal lens. Where Lensfun's model holds the lens the two
agree to float32 precision; where it does not, their distance over the
image is the residual the exporter printed.

Lensfun 0.3.4 (bundled with lensfunpy 1.18.0) has an SSE ``poly3`` kernel
that multiplies each coordinate by its neighbour pixel's factor when it
runs over 4-pixel blocks of a 16-byte aligned buffer (fixed in later
Lensfun): the tests read Lensfun's coordinates in runs of at most 3 pixels,
its plain kernel, which is the formula.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ElementTree
from pathlib import Path

import numpy as np
import pytest

from camcal.base.errors import CamcalError
from camcal.io.interchange import export_rig, import_rig
from camcal.io.lensfun import LensfunLens
from camcal.model.distortion import Distortion
from camcal.model.rig import Camera, Rig

lensfunpy = pytest.importorskip("lensfunpy")


def _camera(size: tuple[int, int], focal: float, model: str, params: dict[str, float], *,
            centre_offset: tuple[float, float] = (0.0, 0.0), sensor_width_mm: float | None = None) -> Camera:
    width, height = size
    K = np.array([[focal, 0.0, (width - 1) / 2 + centre_offset[0]], [0.0, focal, (height - 1) / 2 + centre_offset[1]],
                  [0.0, 0.0, 1.0]])
    return Camera("cam0", size, K, Distortion(model, params), np.eye(3), np.zeros(3), sensor_width_mm=sensor_width_mm)


class _LensfunView:
    """The exported lens as Lensfun reads it, and its pinhole (undistorted) image."""

    def __init__(self, path: Path, size: tuple[int, int]) -> None:
        database = lensfunpy.Database(paths=[str(path)], load_common=False, load_bundled=False)
        [self.lens] = database.lenses
        entry = ElementTree.parse(path).getroot().find("lens")
        distortion = entry.find("calibration/distortion")
        self.model = distortion.get("model")
        self.focal_mm = float(distortion.get("focal"))
        [real] = [float(e.get("real-focal")) for e in entry.findall("calibration/real-focal-length")
                  if float(e.get("focal")) == self.focal_mm]
        self.modifier = lensfunpy.Modifier(self.lens, self.lens.crop_factor, *size)
        self.modifier.initialize(self.focal_mm, 8.0, 1000.0, scale=1.0, flags=lensfunpy.ModifyFlags.DISTORTION)
        aspect = float(entry.findtext("aspect-ratio"))
        unit = (min(size) - 1) / 2
        # Lensfun's geometry unit: F = focal_mm * s / NormalizedInMillimeters (modifier.cpp)
        terms = {name: float(value) for name, value in distortion.attrib.items() if name not in ("model", "focal")}
        self.F = LensfunLens(self.model, terms, self.focal_mm, self.lens.crop_factor, aspect, (0.0, 0.0),
                             real).undistorted_focal_px(size)
        width, height = size
        self.centre = np.array([(width - 1) / 2 + self.lens.center_x * unit,
                                (height - 1) / 2 + self.lens.center_y * unit])

    def distorted(self, undistorted: np.ndarray) -> np.ndarray:
        """Lensfun's source pixel of each undistorted pixel (one call per point: its plain kernel)."""
        return np.array([self.modifier.apply_geometry_distortion(x, y, 1, 1)[0, 0] for x, y in undistorted])

    def rays(self, undistorted: np.ndarray) -> np.ndarray:
        return np.column_stack([(undistorted - self.centre) / self.F, np.ones(len(undistorted))])


def _export(tmp_path: Path, camera: Camera):
    out = tmp_path / "lens.xml"
    result = export_rig(Rig((camera,)), "lensfun", out)
    return out, result


@pytest.mark.parametrize(("size", "focal", "model", "params", "offset", "expected"), [
    ((640, 480), 500.0, "polynomial", {"k1": -0.12, "k2": 0.0}, (0.0, 0.0), "poly3"),
    ((1920, 1080), 1400.0, "polynomial", {"k1": 0.08, "k2": 0.0}, (12.0, -7.5), "poly3"),
    ((600, 800), 450.0, "polynomial", {"k1": -0.2, "k2": 0.09}, (-5.0, 3.0), "poly5"),
])
def test_a_lens_lensfun_holds_corrects_like_camcal_per_pixel(tmp_path, size, focal, model, params, offset, expected):
    camera = _camera(size, focal, model, params, centre_offset=offset, sensor_width_mm=23.5)
    out, result = _export(tmp_path, camera)
    [conversion] = result.conversions
    assert conversion.exact and conversion.target == f"Lensfun {expected}"
    view = _LensfunView(out, size)
    assert view.model == expected
    width, height = size
    # the whole undistorted image, read from Lensfun in runs of 3 pixels (its plain kernel)
    lensfun = np.concatenate([view.modifier.apply_geometry_distortion(x, 0, min(3, width - x), height)
                              for x in range(0, width, 3)], axis=1).reshape(-1, 2)
    ys, xs = np.mgrid[0:height, 0:width]
    pixels = np.column_stack([xs.ravel(), ys.ravel()]).astype(np.float64)
    camcal = camera.distortion.project_rays(view.rays(pixels), camera.K)
    distance = np.linalg.norm(lensfun - camcal, axis=1)
    assert np.sqrt(np.mean(distance**2)) < 0.05 and distance.max() < 0.05
    # the same distortion camcal reads back from the file
    back = import_rig(out, "lensfun").rig.cameras[0]
    np.testing.assert_allclose(back.K, camera.K, atol=1e-4)
    for name, value in params.items():
        assert back.distortion.params[name] == pytest.approx(value, rel=1e-6)


@pytest.mark.parametrize(("size", "focal", "model", "params"), [
    ((640, 480), 520.0, "opencv", {"k1": -0.21, "k2": 0.05, "p1": 0.0008, "p2": -0.0005, "k3": 0.01}),
    ((1280, 720), 900.0, "division", {"lambda": -2.2e-7}),
    ((800, 800), 600.0, "polynomial", {"k1": 0.05, "k2": -0.03, "k3": 0.02}),
])
def test_a_lens_lensfun_does_not_hold_has_the_residual_the_export_printed(tmp_path, size, focal, model, params):
    camera = _camera(size, focal, model, params, centre_offset=(4.0, -3.0))
    out, result = _export(tmp_path, camera)
    [conversion] = result.conversions
    assert not conversion.exact
    assert "RMS" in conversion.describe() and conversion.target.startswith("Lensfun ")
    view = _LensfunView(out, size)
    width, height = size
    grid = np.stack(np.meshgrid(np.linspace(0, width - 1, 41), np.linspace(0, height - 1, 31)), -1).reshape(-1, 2)
    rays = camera.distortion.rays_from_pixels(grid, camera.K)
    undistorted = view.centre + view.F * rays[:, :2] / rays[:, 2:]
    distance = np.linalg.norm(view.distorted(undistorted) - grid, axis=1)
    rms, largest = float(np.sqrt(np.mean(distance**2))), float(distance.max())
    assert rms > 0.005  # a real residual, measured in Lensfun
    assert rms == pytest.approx(conversion.refit.rms_px, rel=0.1, abs=0.005)
    assert largest == pytest.approx(conversion.refit.max_px, rel=0.1, abs=0.005)


def test_crop_factor_and_focal_follow_the_sensor(tmp_path):
    camera = _camera((1920, 1080), 1400.0, "polynomial", {"k1": 0.0, "k2": 0.0}, sensor_width_mm=36.0)
    out, _ = _export(tmp_path, camera)
    entry = ElementTree.parse(out).getroot().find("lens")
    crop = float(entry.findtext("cropfactor"))
    assert crop == pytest.approx(math.hypot(36, 24) / (36 * math.hypot(16, 9) / 16), rel=1e-6)
    # no distortion: the focal written is the camera's, 1400 px of 36 mm / 1920 px (Lensfun's mm: its image's)
    focal = float(entry.find("calibration/distortion").get("focal"))
    assert focal == pytest.approx(1400 * 36 / 1920, rel=2e-3)
    assert float(entry.find("calibration/real-focal-length").get("real-focal")) == pytest.approx(focal, rel=1e-9)


def test_bad_input_one_line_nothing_written(tmp_path):
    camera = _camera((640, 480), 500.0, "polynomial", {"k1": 0.1, "k2": 0.0})
    with pytest.raises(CamcalError, match=r"\.xml"):
        export_rig(Rig((camera,)), "lensfun", tmp_path / "lens.txt")
    assert not list(tmp_path.iterdir())
    other = tmp_path / "other.xml"
    other.write_text("<opencv_storage><K>1</K></opencv_storage>")
    with pytest.raises(CamcalError, match="not a Lensfun database"):
        import_rig(other, "lensfun")
    ptlens = tmp_path / "ptlens.xml"
    ptlens.write_text('<lensdatabase><lens><model>x</model><cropfactor>1</cropfactor><calibration>'
                      '<distortion model="ptlens" focal="20" a="0.01" b="-0.02" c="0.003"/></calibration></lens>'
                      '<!-- camcal image_size 640 480 --></lensdatabase>')
    with pytest.raises(CamcalError, match="odd powers"):
        import_rig(ptlens, "lensfun")


def test_the_cli_exports_and_reads_back_a_lensfun_file(tmp_path, capsys):
    from camcal.cli import main

    camera = _camera((640, 480), 500.0, "opencv", {"k1": -0.2, "k2": 0.04, "p1": 0.0, "p2": 0.0, "k3": 0.0})
    rig_path = Rig((camera,)).save(tmp_path / "in.rig.json")
    out = tmp_path / "lens.xml"
    assert main(["rig", "export", str(rig_path), str(out), "--to", "lensfun"]) == 0
    printed = capsys.readouterr().out
    assert "Lensfun poly5" in printed and "RMS" in printed and f"wrote {out}" in printed
    assert main(["rig", "import", str(out), "--from", "lensfun", "--out", str(tmp_path / "back.rig.json")]) == 0
    back = Rig.load(tmp_path / "back.rig.json").cameras[0]
    # the opencv k1 k2 lens is a polynomial k1 k2 one: poly5 holds it, and it comes back
    assert back.distortion.params["k1"] == pytest.approx(-0.2, rel=1e-6)
    assert back.distortion.params["k2"] == pytest.approx(0.04, rel=1e-6)


@pytest.mark.parametrize(("lens", "message"), [
    ("<model>x</model><calibration/>", "no <cropfactor>"),
    ("<model>x</model><cropfactor>0</cropfactor>", "crop factor must be > 0"),
    ("<model>x</model><cropfactor>1</cropfactor><aspect-ratio>3:0</aspect-ratio>", "aspect-ratio"),
    ("<model>x</model><cropfactor>1</cropfactor><calibration><distortion model='poly3' focal='-3' k1='0.1'/>"
     "</calibration>", "focal lengths > 0"),
    ("<model>x</model><cropfactor>1</cropfactor><calibration><distortion model='acm' focal='3' k1='0.1'/>"
     "</calibration>", "unknown distortion model"),
    ("<model>x</model><cropfactor>1</cropfactor><calibration><distortion model='poly5' focal='3' k1='nan'/>"
     "</calibration>", "not finite"),
])
def test_a_bad_lens_entry_is_one_line(tmp_path, lens, message):
    path = tmp_path / "bad.xml"
    path.write_text(f"<lensdatabase><lens>{lens}</lens><!-- camcal image_size 640 480 --></lensdatabase>")
    with pytest.raises(CamcalError, match=message) as info:
        import_rig(path, "lensfun")
    assert "\n" not in str(info.value)


def _measured(view: _LensfunView, camera: Camera, columns: int = 41, rows: int = 31) -> tuple[float, float]:
    """Max and RMS distance between Lensfun's and camcal's distorted pixels over a grid of the image."""
    width, height = camera.image_size
    grid = np.stack(np.meshgrid(np.linspace(0, width - 1, columns), np.linspace(0, height - 1, rows)),
                    -1).reshape(-1, 2)
    rays = camera.distortion.rays_from_pixels(grid, camera.K)
    distance = np.linalg.norm(view.distorted(view.centre + view.F * rays[:, :2] / rays[:, 2:]) - grid, axis=1)
    return float(distance.max()), float(np.sqrt(np.mean(distance**2)))


def _state_view(path: Path, size: tuple[int, int], focal_mm: float) -> _LensfunView:
    """The view of one focal length of a lens with several: ``F`` from that entry, Lensfun's lens with all."""
    tree = ElementTree.parse(path)
    calibration = tree.getroot().find("lens/calibration")
    for element in list(calibration):
        if float(element.get("focal")) != focal_mm:
            calibration.remove(element)
    single = path.with_name(f"state_{focal_mm:g}.xml")
    tree.write(single)
    view = _LensfunView(single, size)
    database = lensfunpy.Database(paths=[str(path)], load_common=False, load_bundled=False)
    [view.lens] = database.lenses
    view.modifier = lensfunpy.Modifier(view.lens, view.lens.crop_factor, *size)
    view.modifier.initialize(focal_mm, 8.0, 1000.0, scale=1.0, flags=lensfunpy.ModifyFlags.DISTORTION)
    return view


def test_a_zoom_lens_writes_one_entry_per_focal_length_each_matching_in_lensfun(tmp_path):
    from camcal.io.lensfun import export_states

    size = (960, 640)
    states = [(24.0, _camera(size, 700.0, "polynomial", {"k1": -0.15, "k2": 0.0}, centre_offset=(6.0, -4.0))),
              (35.0, _camera(size, 1020.0, "polynomial", {"k1": -0.05, "k2": 0.02}, centre_offset=(6.0, -4.0))),
              (50.0, _camera(size, 1460.0, "polynomial", {"k1": 0.04, "k2": 0.0}, centre_offset=(6.0, -4.0)))]
    out = tmp_path / "zoom.xml"
    result = export_states(states, out, name="Zoom 24-50")
    assert [c.exact for c in result.conversions] == [True, True, True]
    entries = ElementTree.parse(out).getroot().findall("lens/calibration/distortion")
    assert [float(e.get("focal")) for e in entries] == [24.0, 35.0, 50.0]
    for focal, camera in states:
        largest, rms = _measured(_state_view(out, size, focal), camera)
        assert rms < 0.05 and largest < 0.05, (focal, largest, rms)
    # a drifting principal point: Lensfun holds one centre, the drift is the residual printed, measured in Lensfun
    drifting = [(24.0, states[0][1]), (50.0, _camera(size, 1460.0, "polynomial", {"k1": 0.04, "k2": 0.0},
                                                     centre_offset=(-6.0, 8.0)))]
    result = export_states(drifting, out, name="Zoom 24-50")
    for (focal, camera), conversion in zip(drifting, result.conversions):
        assert not conversion.exact
        largest, rms = _measured(_state_view(out, size, focal), camera)
        assert rms == pytest.approx(conversion.refit.rms_px, rel=0.1, abs=0.005)
        assert rms > 1.0  # 12 px by 6 px between the two principal points


def _profile_file(tmp_path: Path, size: tuple[int, int], drift_px: float) -> Path:
    """A lens profile of a zoom from 24 to 70 mm (fx = fy, k1 and k2 changing with focal length, breathing with
    focus), its principal point drifting ``drift_px`` over the range, written as ``zoom.profile.json``."""
    from camcal.geometry.lens_profile import fit_profile
    from camcal.model.lens_profile import LensProfile, LensState, format_state

    parameters = ("fx", "fy", "cx", "cy", "k1", "k2")
    sigma = np.array([1.0, 1.0, 0.3, 0.3, 0.002, 0.01])
    states = []
    for focal in (24.0, 40.0, 70.0):
        for focus in (1.0, math.inf):
            fx = 20.0 * focal * (1.0 + 0.02 / focus)
            drift = drift_px * (focal - 24.0) / 46.0
            values = [fx, fx, (size[0] - 1) / 2 + drift, (size[1] - 1) / 2 - drift / 2,
                      -0.2 + 0.004 * focal, 0.05 - 0.0005 * focal]
            states.append(LensState(format_state(focal, focus), focal, focus, dict(zip(parameters, values)),
                                    np.diag(sigma**2), 8, 0.2))
    fitted = fit_profile(states, parameters)
    profile = LensProfile("polynomial", size, "chessboard:9x6:0.03", parameters, tuple(states), fitted.surfaces)
    return profile.save(tmp_path / "zoom.profile.json")


def test_a_lens_profile_exports_to_lensfun_matching_it_at_each_focal_length(tmp_path, capsys):
    from camcal.cli import main
    from camcal.geometry.lens_profile import camera_at
    from camcal.model.lens_profile import LensProfile

    size = (480, 320)
    path = _profile_file(tmp_path, size, drift_px=0.0)
    out = tmp_path / "zoom.xml"
    assert main(["rig", "export", str(path), str(out), "--to", "lensfun"]) == 0
    printed = capsys.readouterr().out
    assert "at 24 mm" in printed and "poly5 exact" in printed and "farthest focus calibrated (inf)" in printed
    entries = ElementTree.parse(out).getroot().findall("lens/calibration/distortion")
    assert [float(e.get("focal")) for e in entries] == [24.0, 40.0, 70.0]
    profile = LensProfile.load(path)
    for focal in (24.0, 40.0, 70.0):
        camera = camera_at(profile, focal, math.inf)
        largest, rms = _measured(_state_view(out, size, focal), camera)
        assert rms < 0.05 and largest < 0.05, (focal, largest, rms)


def test_a_drifting_principal_point_is_the_lensfun_residual_printed(tmp_path):
    from camcal.api.rig import export_rig
    from camcal.geometry.lens_profile import camera_at
    from camcal.model.lens_profile import LensProfile

    size = (480, 320)
    path = _profile_file(tmp_path, size, drift_px=10.0)
    out = tmp_path / "zoom.xml"
    result = export_rig(path, out, "lensfun")
    profile = LensProfile.load(path)
    for focal, conversion in zip((24.0, 40.0, 70.0), result.conversions):
        camera = camera_at(profile, focal, math.inf)
        largest, rms = _measured(_state_view(out, size, focal), camera)
        assert rms == pytest.approx(conversion.refit.rms_px, rel=0.1, abs=0.005)
    assert max(c.refit.rms_px for c in result.conversions) > 1.0  # 5 px from the mean centre at 24 mm
    with pytest.raises(CamcalError, match="a lens profile exports to lensfun, lens-table, opentrackio, 3de, not 'nuke'"):
        export_rig(path, tmp_path / "zoom.nk", "nuke")
    assert not (tmp_path / "zoom.nk").exists()


def test_a_fisheye_is_lensfuns_fisheye_type_and_corrects_like_camcal(tmp_path):
    size = (960, 640)
    camera = _camera(size, 300.0, "kannala-brandt", {"k1": 0.02, "k2": -0.005, "k3": 0.0, "k4": 0.0},
                     centre_offset=(3.0, -2.0))
    out, result = _export(tmp_path, camera)
    assert ElementTree.parse(out).getroot().findtext("lens/type") == "fisheye"
    assert result.conversions[0].exact
    view = _LensfunView(out, size)
    assert view.lens.type == lensfunpy.LensType.FISHEYE
    # Lensfun's undistorted image of a fisheye is the equidistant one: a ray at theta from the axis at F theta
    undistorted = np.stack(np.meshgrid(np.linspace(0, size[0] - 1, 25), np.linspace(0, size[1] - 1, 17)),
                           -1).reshape(-1, 2)
    offset = (undistorted - view.centre) / view.F
    theta = np.linalg.norm(offset, axis=1)
    rays = np.column_stack([offset * (np.sin(theta) / np.where(theta > 0, theta, 1.0))[:, None], np.cos(theta)])
    distance = np.linalg.norm(view.distorted(undistorted) - camera.distortion.project_rays(rays, camera.K), axis=1)
    assert distance.max() < 0.05, distance.max()
    # read back: the same Kannala-Brandt lens
    [back] = import_rig(out, "lensfun").rig.cameras
    assert back.distortion.model == "kannala-brandt"
    np.testing.assert_allclose(back.K, camera.K, rtol=1e-7)  # 9 significant digits in the file
    for name, value in camera.distortion.params.items():
        assert back.distortion.params[name] == pytest.approx(value, rel=1e-7, abs=1e-12)


def test_a_wide_rectilinear_lens_has_finite_border_residuals(tmp_path):
    # a division lens imaging rays near 90 degrees at the overscan border: the pinhole lens Lensfun writes does
    # not image those rays (counted as lost), the others' residuals are pixels, not 1e11
    camera = _camera((960, 640), 350.0, "division", {"lambda": -2e-6})
    _, result = _export(tmp_path, camera)
    refit = result.conversions[0].refit
    assert refit.n_lost > 0
    assert refit.border_max_px < math.hypot(960, 640)
