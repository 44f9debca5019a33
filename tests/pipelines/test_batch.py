"""Batch processing of plate sequences on Dask: same pixels as the single-frame paths, bit for bit.

The cluster tests start a real ``distributed.LocalCluster`` with 2 worker
PROCESSES (``processes=True``, one thread each); the kill test starts
``python -m camcal batch`` in its own process group and SIGKILLs it while a
worker is blocked on an input that is a FIFO (so the kill lands midway,
deterministically), then resumes with ``--resume``.
"""

import dataclasses
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import OpenEXR
import pytest

from camcal.pipelines.batch import (
    ColourStep, make_job, process_frame, record_path, run_batch,
)
from camcal.cli import main
from camcal.colour.fit.characterise import characterise
from camcal.colour.chart.patches import PatchSet
from camcal.base.errors import CamcalError
from camcal.model.distortion import Distortion
from camcal.geometry.undistort import make_undistorter
from camcal.io.frames import read_frame
from camcal.model.rig import Rectification, Rig
from camcal.synthetic import example_camera
from camcal.io.colourfile import save_colour_file
from dask_faults import workers_elsewhere

import cv2  # noqa: E402  (after camcal.io.frames: EXR enabled in OpenCV)

SIZE = (160, 120)
FRAMES = tuple(range(1001, 1013))
ROOT = Path(__file__).resolve().parents[2]


# -- fixtures -----------------------------------------------------------------------


def _rig(tmp: Path) -> Path:
    left = example_camera("left", image_size=SIZE, fx=150.0, fy=149.0, principal_point=(80.3, 59.1),
                          distortion=Distortion("division", {"lambda": -6e-6}, center=(81.0, 58.0)))
    # a rectification: a small rotation about y and a new K on a slightly larger canvas
    angle = 0.03
    R = np.array([[np.cos(angle), 0, np.sin(angle)], [0, 1, 0], [-np.sin(angle), 0, np.cos(angle)]])
    K_rect = np.array([[140.0, 0, 86.0], [0, 140.0, 62.0], [0, 0, 1]])
    left = dataclasses.replace(left, rectification=Rectification(K_rect @ R @ np.linalg.inv(left.K), K_rect, (172, 124)))
    right = example_camera("right", image_size=SIZE, centre=(0.9, -6.0, 1.4),
                           distortion=Distortion("polynomial", {"k1": -0.1, "k2": 0.01}))
    return Rig((left, right)).save(tmp / "set.rig.json")


def _plate(frame: int) -> np.ndarray:
    """(H, W, 3) values in [0, 1]: a smooth pattern plus seeded noise, different per frame."""
    rng = np.random.default_rng(frame)
    v, u = np.mgrid[0 : SIZE[1], 0 : SIZE[0]]
    base = 0.5 + 0.4 * np.sin(u[..., None] / (5.0 + np.arange(3)) + frame) * np.cos(v[..., None] / 7.0)
    return np.clip(base + 0.05 * rng.standard_normal(base.shape), 0.0, 1.0)


def _write_exr(path: Path, frame: int, dtype=np.float16) -> None:
    rgb = _plate(frame).astype(dtype)
    planes = {"R": rgb[..., 0], "G": rgb[..., 1], "B": rgb[..., 2], "A": np.ones(SIZE[::-1], np.float32)}
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "owner": "plate dept", "capDate": f"2025:01:01 00:00:{frame % 60:02d}"}
    with OpenEXR.File(header, planes) as exr:
        exr.write(str(path))


def _write_png16(path: Path, frame: int) -> None:
    cv2.imwrite(str(path), np.round(_plate(frame) * 65535).astype(np.uint16))


def _sequence(tmp: Path, kind: str, frames=FRAMES) -> str:
    (tmp / "plates").mkdir(exist_ok=True)
    suffix = {"exr": "exr", "exr-float": "exr", "png16": "png"}[kind]
    pattern = str(tmp / "plates" / f"left.%04d.{suffix}")
    for frame in frames:
        if kind == "png16":
            _write_png16(Path(pattern % frame), frame)
        else:
            _write_exr(Path(pattern % frame), frame, np.float16 if kind == "exr" else np.float32)
    return pattern


@pytest.fixture(scope="module")
def fit(sim):
    """A characterisation of the simulated Nikon (codes = linear RGB scaled into [0, 1]); it bakes."""
    scale = 1.0 / np.max(sim.RGB_train)
    train = PatchSet(sim.names_train, sim.RGB_train * scale, sim.XYZ_train)
    return characterise(train, white="D65", model="polynomial:7", loo=False).fit


@pytest.fixture(scope="module")
def client():
    """A real LocalCluster: 2 worker processes, one thread each."""
    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=":0") as cluster, \
            Client(cluster) as dask:
        yield dask


def _single_process(job, frames, out_dir: Path):
    """The reference: the same frames through process_frame in this process, no Dask."""
    local = dataclasses.replace(job, out_pattern=str(out_dir / Path(job.out_pattern).name))
    for frame in frames:
        process_frame(frame, local)
    return local


# -- single process against the existing single-frame paths --------------------------


def test_batch_undistort_equals_camcal_undistort_bit_for_bit(tmp_path):
    rig = _rig(tmp_path)
    pattern = _sequence(tmp_path, "png16", FRAMES[:3])
    job = make_job(rig, "left", pattern, str(tmp_path / "batch" / "left.%04d.png"), "undistort", mode="keep")
    for frame in FRAMES[:3]:
        result = process_frame(frame, job)
        assert Path(result.output).exists()
    inputs = [pattern % frame for frame in FRAMES[:3]]
    assert main(["undistort", str(rig), "--camera", "left", "--images", *inputs, "--mode", "keep", "--out", str(tmp_path / "single")]) == 0
    for frame in FRAMES[:3]:
        ours = cv2.imread(str(tmp_path / "batch" / f"left.{frame}.png"), cv2.IMREAD_UNCHANGED)
        peer = cv2.imread(str(tmp_path / "single" / f"left.{frame}.png"), cv2.IMREAD_UNCHANGED)
        assert ours.dtype == np.uint16 and ours.shape[:2] != (SIZE[1], SIZE[0])  # keep: a larger canvas
        np.testing.assert_array_equal(ours, peer)


def test_exr_half_keeps_types_header_and_equals_the_undistorter(tmp_path):
    rig = _rig(tmp_path)
    pattern = _sequence(tmp_path, "exr", FRAMES[:1])
    job = make_job(rig, "left", pattern, str(tmp_path / "out" / "left.%04d.exr"), "undistort")
    process_frame(FRAMES[0], job)
    with OpenEXR.File(str(tmp_path / "out" / "left.1001.exr"), separate_channels=True) as exr:
        header = dict(exr.header())
        planes = {name: channel.pixels.copy() for name, channel in exr.channels().items()}
    assert {name: plane.dtype for name, plane in planes.items()} == {
        "R": np.float16, "G": np.float16, "B": np.float16, "A": np.float32}
    assert header["owner"] == "plate dept" and header["capDate"] == "2025:01:01 00:00:41"
    source = read_frame(pattern % FRAMES[0])
    expected = make_undistorter(Rig.load(rig).camera("left")).apply(source.pixels)
    for i, name in enumerate(source.channels):
        np.testing.assert_array_equal(planes[name], expected[:, :, i].astype(planes[name].dtype))


@pytest.fixture(scope="module")
def matrix_fit(sim):
    """A 3x3 matrix characterisation of the simulated Nikon: its OCIO processor is exact."""
    scale = 1.0 / np.max(sim.RGB_train)
    train = PatchSet(sim.names_train, sim.RGB_train * scale, sim.XYZ_train)
    return characterise(train, white="D65", model="matrix3x3", loo=False).fit


def _space_of(XYZ, white, space):
    """colour-science's own conversion of the fit's XYZ to an output space (Bradford), the peer."""
    import colour

    if space == "CIE XYZ":
        return XYZ
    name = {"ACES2065-1": "ACES2065-1", "ACEScg": "ACEScg", "lin Rec.709": "ITU-R BT.709"}[space]
    return colour.XYZ_to_RGB(XYZ, name, illuminant=colour.XYZ_to_xy(white), chromatic_adaptation_transform="Bradford")


def test_colour_step_writes_the_chosen_space(tmp_path, matrix_fit):
    rig = _rig(tmp_path)
    fit_path = save_colour_file(matrix_fit, tmp_path / "left.colour.json")
    for kind, space in (("exr-float", "ACEScg"), ("png16", "lin Rec.709"), ("exr-float", "CIE XYZ")):
        pattern = _sequence(tmp_path, kind, FRAMES[:1])
        suffix = Path(pattern).suffix
        out_pattern = str(tmp_path / kind / space.replace(" ", "_") / f"c.%04d{suffix}")
        job = make_job(rig, "left", pattern, out_pattern, None, fit_path, colour_space=space)
        process_frame(FRAMES[0], job)
        source, out = read_frame(pattern % FRAMES[0]), read_frame(out_pattern % FRAMES[0])
        rgb = [source.channel_index(c) for c in "RGB"]
        top = 65535.0 if kind == "png16" else 1.0
        XYZ = matrix_fit.apply_codes(source.pixels[:, :, rgb].reshape(-1, 3) / top)
        expected = _space_of(XYZ, matrix_fit.target_white_XYZ, space).reshape(SIZE[1], SIZE[0], 3)
        if kind == "exr-float":  # a matrix fit: exact up to float32 arithmetic
            np.testing.assert_allclose(out.pixels[:, :, rgb], expected, rtol=1e-5, atol=2e-6)
            np.testing.assert_array_equal(out.pixels[:, :, source.channel_index("A")], 1.0)
        else:  # quantised back to 16 bit: within one code value of the float64 result
            assert np.abs(out.pixels[:, :, rgb] - np.clip(expected, 0, 1) * top).max() <= 1.0
        if space != "CIE XYZ":  # RGB, not XYZ, in the RGB channels
            assert np.abs(expected - XYZ.reshape(expected.shape)).max() > 0.05
    with pytest.raises(CamcalError, match="unknown .* space .sRGB."):
        make_job(rig, "left", pattern, str(tmp_path / "x.%04d.exr"), None, fit_path, colour_space="sRGB")


@pytest.mark.parametrize("space", ["ACES2065-1", "ACEScg", "lin Rec.709", "CIE XYZ"])
def test_colour_step_class_applies_the_baked_fit_within_its_bake_error(sim, fit, space):
    """A polynomial fit goes through the baked Lut3D: within CIEDE2000 0.2 of the numpy fit on
    independent colours (190 reflectances the fit never saw), converted back to XYZ."""
    from camcal.colour.difference import delta_E
    from camcal.colour.export.ocio_fit import output_matrix

    codes = (sim.RGB_test / np.max(sim.RGB_train)).astype(np.float32).reshape(10, 19, 3)
    step = ColourStep(fit, space)
    assert step.kind == "lut3d" and step.processor.bake_error.max <= 0.2
    out = step.apply(codes.copy())
    assert out.dtype == np.float32 and out.shape == codes.shape
    XYZ = out.reshape(-1, 3).astype(np.float64) @ np.linalg.inv(output_matrix(fit.target_white_XYZ, space)).T
    truth = fit.apply_codes(codes.reshape(-1, 3).astype(np.float64))
    assert delta_E(XYZ, truth, fit.target_white_XYZ).max() < 0.2
    np.testing.assert_allclose(out.reshape(-1, 3), _space_of(truth, fit.target_white_XYZ, space), atol=0.01)


# -- a real Dask LocalCluster ----------------------------------------------------------


@pytest.mark.parametrize("kind,geometry", [("exr", "undistort"), ("png16", "rectify")])
def test_two_worker_cluster_equals_single_process_bit_for_bit(tmp_path, client, fit, kind, geometry):
    rig = _rig(tmp_path)
    pattern = _sequence(tmp_path, kind, FRAMES)
    suffix = Path(pattern).suffix
    job = make_job(rig, "left", pattern, str(tmp_path / "dask" / f"left.%04d{suffix}"), geometry,
                   save_colour_file(fit, tmp_path / "left.colour.json"))
    report = run_batch(job, FRAMES, client=client, progress=False)
    assert report.ok and report.n_workers == 2
    assert [r.frame for r in report.written] == list(FRAMES)
    workers = {r.worker for r in report.written}
    assert len(workers) == 2 and os.getpid() not in {int(w.split(":")[1]) for w in workers}
    # maps and colour step built once per worker process, not per frame
    assert len({r.processor for r in report.written}) == len(workers)
    reference = _single_process(job, FRAMES, tmp_path / "single")
    for frame in FRAMES:
        ours, peer = job.output_path(frame), reference.output_path(frame)
        assert ours.read_bytes() == peer.read_bytes()
    if geometry == "rectify":
        assert read_frame(job.output_path(FRAMES[0])).size == (172, 124)


def test_relative_patterns_reach_workers_in_another_working_directory(tmp_path, client, monkeypatch):
    """A farm's workers do not share the client's working directory: patterns relative to the client's still work."""
    rig = _rig(tmp_path)
    pattern = _sequence(tmp_path, "png16", FRAMES[:3])
    monkeypatch.chdir(tmp_path)
    relative = str(Path(pattern).relative_to(tmp_path))
    job = make_job(rig, "left", relative, "out/left.%04d.png", "undistort")
    with workers_elsewhere(client, tmp_path / "worker"):
        report = run_batch(job, FRAMES[:3], client=client, progress=False)
    assert report.ok and [r.frame for r in report.written] == list(FRAMES[:3])
    reference = _single_process(job, FRAMES[:3], tmp_path / "single")
    for frame in FRAMES[:3]:
        assert (tmp_path / job.output_path(frame)).read_bytes() == reference.output_path(frame).read_bytes()


def test_corrupt_frame_is_reported_by_number_and_the_others_are_written(tmp_path, capsys):
    rig = _rig(tmp_path)
    pattern = _sequence(tmp_path, "exr", FRAMES[:6])
    Path(pattern % 1003).write_bytes(Path(pattern % 1003).read_bytes()[:600])  # truncated
    out = str(tmp_path / "out" / "left.%04d.exr")
    code = main(["batch", str(rig), "--camera", "left", "--images", pattern, "--frames", "1001-1006",
                 "--undistort", "--out", out, "--workers", "2", "--retries", "1", "--quiet", "--json"])
    captured = capsys.readouterr()
    printed = captured.err  # with --json the human summary goes to stderr, the JSON object to stdout
    summary = json.loads(captured.out)
    assert summary["verb"] == "batch" and summary["exit_code"] == 1
    assert summary["figures"]["n_frames"] == 6 and summary["figures"]["n_written"] == 5
    assert list(summary["figures"]["failed"]) == ["1003"] and len(summary["files"]) == 5
    assert code == 1
    assert "FAILED 1 frame(s): 1003" in printed and "frame 1003: cannot read" in printed
    written = sorted(p.name for p in (tmp_path / "out").glob("left.*.exr"))
    assert written == [f"left.{f}.exr" for f in (1001, 1002, 1004, 1005, 1006)]
    assert not [p for p in (tmp_path / "out").iterdir() if p.name.startswith(".left.")]  # no temporaries


# -- kill midway, then --resume ------------------------------------------------------------


def _outputs(directory: Path) -> dict[str, os.stat_result]:
    return {p.name: p.stat() for p in directory.glob("left.*.exr")} if directory.is_dir() else {}


def test_killed_run_resumes_with_every_frame_once(tmp_path, capsys):
    rig = _rig(tmp_path)
    blocked = 1007
    pattern = _sequence(tmp_path, "exr", [f for f in FRAMES if f != blocked])
    os.mkfifo(pattern % blocked)  # a worker that opens it waits for a writer: the run cannot finish
    out_dir = tmp_path / "out"
    command = ["batch", str(rig), "--camera", "left", "--images", pattern, "--frames", f"{FRAMES[0]}-{FRAMES[-1]}",
               "--undistort", "--out", str(out_dir / "left.%04d.exr"), "--workers", "1", "--quiet"]
    env = dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""))
    process = subprocess.Popen([sys.executable, "-m", "camcal", *command], cwd=tmp_path, env=env,
                               stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
    try:
        deadline, seen, since = time.monotonic() + 120, -1, time.monotonic()
        while time.monotonic() < deadline and process.poll() is None:
            count = len(_outputs(out_dir))
            if count != seen:
                seen, since = count, time.monotonic()
            elif count > 0 and time.monotonic() - since > 1.5:
                break  # no progress for 1.5 s: the worker is blocked on the FIFO
            time.sleep(0.05)
        assert process.poll() is None, "the run ended before it was killed"
    finally:
        os.killpg(process.pid, signal.SIGKILL)  # the driver, its nanny and worker processes
        process.wait(timeout=30)
    before = _outputs(out_dir)
    assert 0 < len(before) < len(FRAMES) - 1
    runs = {json.loads(record_path(out_dir / name).read_text())["run"] for name in before}
    assert len(runs) == 1
    # a temporary file of an interrupted write, as a kill during a write leaves
    stale = out_dir / f".left.{blocked}.exr.camcal-tmp.abc12345.exr"
    stale.write_bytes(b"partial")

    os.unlink(pattern % blocked)
    _write_exr(Path(pattern % blocked), blocked)
    assert main(command + ["--resume"]) == 0
    printed = capsys.readouterr().out
    assert f"skipped {len(before)} frame(s) already complete" in printed
    assert f"wrote {len(FRAMES) - len(before)} / {len(FRAMES)} frames" in printed
    after = _outputs(out_dir)
    assert sorted(after) == [f"left.{f}.exr" for f in FRAMES] and not stale.exists()
    camera = Rig.load(rig).camera("left")
    undistorter = make_undistorter(camera)
    second_runs = set()
    for frame in FRAMES:
        name = f"left.{frame}.exr"
        record = json.loads(record_path(out_dir / name).read_text())
        if name in before:  # done by the killed run: not touched again
            assert (after[name].st_ino, after[name].st_mtime_ns) == (before[name].st_ino, before[name].st_mtime_ns)
            assert record["run"] in runs
        else:
            second_runs.add(record["run"])
        # every frame complete and valid: the undistorted plate, all channels
        source, out = read_frame(pattern % frame), read_frame(out_dir / name)
        # each channel stored in its own type (R, G, B HALF; A FLOAT): OpenCV 5's exact bilinear
        # remap leaves A at the border at values no HALF holds (OpenCV 4's 1/32 px weights did not)
        warped = undistorter.apply(source.pixels)
        expected = np.stack([warped[:, :, i].astype(t).astype(np.float32) for i, t in enumerate(source.exr_types)], axis=2)
        np.testing.assert_array_equal(out.pixels, expected)
    assert len(second_runs) == 1 and not second_runs & runs


# -- the command line ---------------------------------------------------------------------


def test_help():
    with pytest.raises(SystemExit) as exit_info:
        main(["batch", "--help"])
    assert exit_info.value.code == 0


@pytest.mark.parametrize("change", [
    {"rig": "missing.rig.json"},
    {"--frames": "1010-1001"},
    {"--frames": "1001-1003"},  # 1003 missing: named, nothing written
    {"--camera": "centre"},
    {"--images": "plates/left.exr"},
    {"--out": "out/left.exr"},
    {"--out": "out/left.%04d.png"},
    {"--images": "elsewhere/left.%04d.exr"},
    {"--rectify": None, "camera": "right"},
    {"--undistort": "drop"},
])
def test_bad_input_exits_2_and_writes_nothing(tmp_path, monkeypatch, capsys, change):
    monkeypatch.chdir(tmp_path)
    _rig(tmp_path)
    _sequence(tmp_path, "exr", FRAMES[:2])
    args = {"rig": "set.rig.json", "--camera": "left", "--images": "plates/left.%04d.exr", "--frames": "1001-1002",
            "--out": "out/left.%04d.exr", "--undistort": None}
    if "camera" in change:
        args["--camera"] = change.pop("camera")
        args.pop("--undistort")
    for key, value in change.items():
        if value == "drop":
            args.pop(key)
        else:
            args[key] = value
    argv = ["batch", args.pop("rig")]
    for key, value in args.items():
        argv += [key] if value is None else [key, value]
    assert main(argv) == 2
    error = capsys.readouterr().err
    assert error.startswith("camcal: error: ") and error.count("\n") == 1
    assert not (tmp_path / "out").exists()


def test_existing_scheduler_by_address(tmp_path, client):
    rig = _rig(tmp_path)
    pattern = _sequence(tmp_path, "exr", FRAMES[:4])
    job = make_job(rig, "left", pattern, str(tmp_path / "out" / "left.%04d.exr"), "rectify")
    report = run_batch(job, FRAMES[:4], scheduler=client.scheduler.address, progress=False)
    assert report.ok and report.n_workers == 2 and len(report.written) == 4
    reference = _single_process(job, FRAMES[:4], tmp_path / "single")
    assert all(job.output_path(f).read_bytes() == reference.output_path(f).read_bytes() for f in FRAMES[:4])
