"""A lens profile as OpenTrackIO lens samples and as 3DEqualizer dynamic distortion, written and read back.

The profile is fitted to synthetic lens states (a zoom breathing with focus, its distortion and principal point
moving). Each file is read back by camcal and compared with the profile's camera at every state written; the
OpenTrackIO numbers are also evaluated by the test's own reading of OpenLensIO's model (screen coordinates in mm
on the sensor, the Brown-Conrady form of its equation (16), undistorted to distorted), so a wrong normalisation
cannot hide behind a reader that shares it.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

import camcal
from camcal.cli import main
from camcal.geometry.lens_profile import camera_at, fit_profile
from camcal.io.conversion import max_pixel_residual
from camcal.model.distortion import frame_grid
from camcal.model.lens_profile import LensProfile, LensState, format_state

SIZE = (960, 640)
SENSOR_WIDTH_MM = 24.0
FOCALS, FOCUSES = (24.0, 50.0), (1.2, math.inf)


def _profile(model: str, focuses: tuple[float, ...] = FOCUSES) -> LensProfile:
    """A smooth zoom over the grid of states: fx linear in the focal length, breathing 3 % per dioptre, the lens
    and the principal point moving with both (noise-free, each sigma 1e-4 of its value)."""
    names = {"opencv": ("k1", "k2", "p1", "p2", "k3"), "division": ("lambda",)}[model]
    parameters = ("fx", "fy", "cx", "cy", *names)
    states = []
    for focal in FOCALS:
        for focus in focuses:
            vergence = 0.0 if math.isinf(focus) else 1.0 / focus
            fx = 20.0 * focal * (1.0 + 0.03 * vergence)
            lens = {"opencv": [-0.12 + 0.002 * focal, 0.03, 4e-4, -3e-4, -0.004],
                    "division": [-4e-7 * (1.0 + 0.01 * focal)]}[model]
            values = [fx, fx, 479.5 + 0.05 * focal, 319.5 - 1.5 * vergence, *lens]
            states.append(LensState(format_state(focal, focus), focal, focus, dict(zip(parameters, values)),
                                    np.diag((1e-4 * np.abs(values)) ** 2), 8, 0.1))
    fitted = fit_profile(states, parameters)
    return LensProfile(model, SIZE, "chessboard:8x6:0.03", parameters, tuple(states), fitted.surfaces)


@pytest.fixture(scope="module", params=["opencv", pytest.param("division", marks=pytest.mark.slow)])
def profile_file(request, tmp_path_factory):
    """The exact case (OpenCV's lens) fast; a lens refitted at every state slow (its fast sibling:
    :func:`test_a_lens_brown_conrady_does_not_hold_is_refitted_and_its_residual_is_the_files`)."""
    path = tmp_path_factory.mktemp("profile") / f"{request.param}.profile.json"
    return _profile(request.param).save(path)


def _opentrackio_project(lens: dict, rays: np.ndarray, pitch: np.ndarray) -> np.ndarray:
    """Pixels of ``rays`` by OpenLensIO's projection matrix characterisation with ``Brown-Conrady U-D``:
    ``eps_u = F x + dP``, ``eps_d = D(eps_u - dP) + dP`` in mm from the sensor's centre, then pixels (camcal's
    pixel (0, 0) at the centre of the top-left pixel: the sensor's centre is pixel ``(size - 1) / 2``)."""
    [distortion] = lens["distortion"]
    assert distortion["model"] == "Brown-Conrady U-D"
    k1, k2, k3, k4, k5, k6 = distortion["radial"]
    p1, p2 = distortion["tangential"]
    F = lens["pinholeFocalLength"]
    x, y = (F * rays[:, :2] / rays[:, 2:]).T  # eps_u - dP, mm
    r2 = x * x + y * y
    radial = (1 + k1 * r2 + k3 * r2**2 + k5 * r2**3) / (1 + k2 * r2 + k4 * r2**2 + k6 * r2**3)
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + 2 * p2 * x * y + p1 * (r2 + 2 * y * y)
    offset = np.array([lens["projectionOffset"]["x"], lens["projectionOffset"]["y"]])
    return (np.column_stack([xd, yd]) + offset) / pitch + (np.array(SIZE) - 1) / 2


def _rays(camera) -> np.ndarray:
    pixels = frame_grid(camera.image_size, 40.0)
    ideal = camera.distortion.undistort(pixels, camera.K)
    return np.column_stack([ideal, np.ones(len(ideal))]) @ np.linalg.inv(camera.K).T


def test_a_profile_as_opentrackio_lens_samples_reads_back_to_its_printed_residual(profile_file, tmp_path, capsys):
    profile = LensProfile.load(profile_file)
    out = tmp_path / "lens.json"
    code = main(["rig", "export", str(profile_file), str(out), "--to", "opentrackio", "--sensor-width",
                 str(SENSOR_WIDTH_MM)])
    printed = capsys.readouterr().out
    assert code == 0, printed
    result = camcal.export_rig(profile_file, tmp_path / "api.json", "opentrackio", sensor_width_mm=SENSOR_WIDTH_MM)
    assert (tmp_path / "api.json").read_bytes() == out.read_bytes()
    [conversion] = result.conversions
    print(printed)
    data = json.loads(out.read_text())
    dimensions = data["static"]["camera"]["activeSensorPhysicalDimensions"]
    assert dimensions["width"] == SENSOR_WIDTH_MM and dimensions["height"] == pytest.approx(SENSOR_WIDTH_MM * 640 / 960)
    pitch = np.array([dimensions["width"] / SIZE[0], dimensions["height"] / SIZE[1]])
    back = camcal.import_rig(out, "opentrackio").rig
    assert len(back.frames) == len(data["samples"]) == 3 * 3
    worst = 0.0
    for frame, sample in zip(back.frames, data["samples"]):
        lens = sample["lens"]
        state = back.frames[frame.index].lenses["camera"]
        focal, focus = state.focal_mm, math.inf if state.focus_m is None else state.focus_m
        expected = profile.from_encoders(lens["encoders"]["zoom"], lens["encoders"]["focus"])
        assert focal == pytest.approx(float(expected[0]), rel=1e-12)
        assert (math.isinf(focus) and "focusDistance" not in lens) or focus == pytest.approx(lens["focusDistance"])
        truth = camera_at(profile, focal, focus)
        read = back.camera_at_frame("camera", frame.index)
        worst = max(worst, max_pixel_residual(truth, read))
        # the file's numbers, read by OpenLensIO's own equations, project the profile's rays where it does
        rays = _rays(truth)
        theirs = _opentrackio_project(lens, rays, pitch)
        assert np.max(np.linalg.norm(theirs - truth.project(rays), axis=1)) <= conversion.max_px + 1e-9
        assert lens["distortion"][0]["overscan"] >= 1.0
    assert worst == pytest.approx(conversion.max_px, rel=1e-9, abs=1e-12)
    if profile.model == "opencv":  # Brown-Conrady holds OpenCV's lens: exact
        assert conversion.exact and conversion.max_px < 1e-6, conversion.describe()
    else:  # the division lens is refitted to OpenCV's k1 k2 p1 p2 k3, its residual printed
        assert not conversion.exact and conversion.refit is not None and 0.0 < conversion.max_px < 1.0
        assert "refit" in printed and f"{conversion.refit.max_px:.3g} px" in printed
    barrel = data["samples"][0]["lens"]["distortion"][0]
    assert barrel["overscan"] > 1.0 and data["static"]["lens"]["distortionOverscanMax"] >= barrel["overscan"]


def test_a_lens_brown_conrady_does_not_hold_is_refitted_and_its_residual_is_the_files(tmp_path):
    """One state of a division lens: refitted to OpenCV's k1 k2 p1 p2 k3, and the residual printed is where the
    file's numbers, read by OpenLensIO's equations, put the lens' rays."""
    from camcal.io.opentrackio import LensSample, write_opentrackio_lens

    profile = _profile("division")
    truth = camera_at(profile, 35.0, 2.0)
    out = tmp_path / "lens.json"
    result = write_opentrackio_lens(out, [LensSample(0.4, 0.3, 35.0, 2.0, truth)], name="division",
                                    sensor_width_mm=SENSOR_WIDTH_MM, focal_range=(24.0, 50.0),
                                    focus_range=(1.2, math.inf))
    [conversion] = result.conversions
    assert not conversion.exact and conversion.refit.family == "opencv" and 0.0 < conversion.max_px < 1.0
    [sample] = json.loads(out.read_text())["samples"]
    assert sample["lens"]["focusDistance"] == 2.0
    pitch = np.full(2, SENSOR_WIDTH_MM / SIZE[0])  # square pixels: fy = fx
    rays = _rays(truth)
    distance = np.linalg.norm(_opentrackio_project(sample["lens"], rays, pitch) - truth.project(rays), axis=1)
    assert np.max(distance) <= conversion.max_px + 1e-9 and np.max(distance) > 0.5 * conversion.max_px
    read = camcal.import_rig(out, "opentrackio").rig
    assert read.frames[0].lenses["camera"].focal_mm == pytest.approx(24.0 + 0.4 * 26.0)
    assert read.frames[0].lenses["camera"].focus_m == pytest.approx(1.0 / (0.3 / 1.2))


def test_opentrackio_needs_the_sensor_width_and_a_profile(profile_file, tmp_path, capsys):
    out = tmp_path / "lens.json"
    code = main(["rig", "export", str(profile_file), str(out), "--to", "opentrackio"])
    err = capsys.readouterr().err
    assert code != 0 and "--sensor-width" in err and len(err.strip().splitlines()) == 1 and not out.exists()
    rig = camcal.lens_rig(profile_file, 35.0, 1.2).rig
    with pytest.raises(camcal.CamcalError, match="exports a lens profile"):
        camcal.export_rig(rig, out, "opentrackio")
    assert not out.exists()


def _check_tde_read_back(profile: LensProfile, path, mode: str, n_states: int) -> None:
    """Write ``profile`` as a 3DE lens file at ``path``, read it back: every state within the printed residual."""
    result = camcal.export_rig(profile, path, "3de")
    [conversion] = result.conversions
    text = path.read_text()
    assert mode in text.splitlines()[2] and conversion.describe().count(mode) == 1
    back = camcal.import_rig(path, "3de").rig
    name = back.cameras[0].name
    assert len(back.frames) == n_states
    for frame in back.frames:
        state = frame.lenses[name]
        focus = camcal.api.profile.TDE_INFINITY_M if state.focus_m is None else state.focus_m
        truth = camera_at(profile, state.focal_mm, focus)
        # within the worst state's refit residual, measured on the refit's dense grid (this one is coarser)
        assert max_pixel_residual(truth, back.camera_at_frame(name, frame.index)) <= 1.01 * conversion.max_px + 1e-9
    assert not conversion.exact and 0.0 < conversion.max_px < 2.0
    if math.isinf(profile.focus_range[1]) and profile.focus_range[0] != profile.focus_range[1]:
        assert any("10 km" in note for note in result.notes)


def test_a_zoom_profile_as_3de_dynamic_distortion_over_focal_length_reads_back():
    """The fast sibling of the zoom and focus profile below: one focus, the curves over focal length."""
    import tempfile
    from pathlib import Path

    with tempfile.TemporaryDirectory() as folder:
        _check_tde_read_back(_profile("opencv", (1.2,)), Path(folder) / "lens.txt",
                             "DISTORTION_DYNAMIC_FOCAL_LENGTH", 3)


@pytest.mark.slow
def test_a_zoom_and_focus_profile_as_3de_dynamic_distortion_reads_back(tmp_path):
    """Focal length and focus both change: 3DE's 2D LUT over both, infinity keyed at 10 km."""
    _check_tde_read_back(_profile("opencv"), tmp_path / "lens.txt", "DISTORTION_DYNAMIC_FOCAL_AND_FOCUS_DISTANCE",
                         9)


def test_a_lens_camcal_cannot_hold_is_one_line_and_no_rig(tmp_path, capsys):
    """OpenLensIO's default direction (distorted to undistorted) and a distortion centre off the principal point
    have no camcal lens: refused in one line naming the file, no rig written."""
    from camcal.io.opentrackio import LensSample, write_opentrackio_lens

    out = tmp_path / "lens.json"
    truth = camera_at(_profile("opencv"), 30.0, 2.0)
    samples = [LensSample(0.0, 0.0, 30.0, 2.0, truth), LensSample(1.0, 0.0, 30.0, 2.0, truth)]
    write_opentrackio_lens(out, samples, name="lens", sensor_width_mm=SENSOR_WIDTH_MM, focal_range=(24.0, 50.0),
                           focus_range=(1.2, math.inf))
    data = json.loads(out.read_text())
    for change, message in ((lambda lens: lens["distortion"][0].update(model="Brown-Conrady D-U"), "U-D"),
                            (lambda lens: lens["distortionOffset"].update(x=0.1), "distortion offset")):
        broken = json.loads(json.dumps(data))
        change(broken["samples"][1]["lens"])
        path = tmp_path / "broken.json"
        path.write_text(json.dumps(broken))
        rig = tmp_path / "back.rig.json"
        code = main(["rig", "import", str(path), "--from", "opentrackio", "--out", str(rig)])
        err = capsys.readouterr().err
        assert code != 0 and len(err.strip().splitlines()) == 1 and str(path) in err and message in err, err
        assert "samples[1]" in err and not rig.exists()
