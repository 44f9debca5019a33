"""Matchmove of rendered plates: camcal solve against Blender's tracker and plain pycolmap, and its cost growth.

Plates (640 x 360, 24 fps, a polynomial lens k1 -0.06, k2 0.008, f 480 px,
principal point 2.9 / -1.4 px off the centre) are ray-cast through camcal's
own lens mapping (:func:`camcal.synthetic.render_planes`: every pixel's ray
through the lens's exact inverse) in a closed textured set (floor, four
walls, three boxes; :func:`camcal.synthetic.orbit_set_planes`):

- ``walk``: a handheld walk around the boxes (0.45 m/s, step bob, sway and
  hand shake of about 0.5 deg), looking 35 deg inwards of the way ahead;
- ``dolly``: a slow lateral dolly (1.5 m) with a 30 deg pan, no shake;
- ``loop``: a full orbit around the boxes that returns to its start;
- ``walk-blur``: the walk with motion blur (a 180 deg shutter: the mean of 5
  renders across the half frame interval centred on the frame's time).

Methods, each in its own process (wall time of the solve alone, the
process's peak resident memory from ``getrusage``), on the same PNG frames:

- ``camcal``: ``camcal.api.solve`` with ``matcher="sequential"``, every
  other option its default (lens model chosen by held-out residual);
- ``camcal-held``: the same with ``intrinsics=`` the true lens (a rig file
  of the rendering camera; the lens held);
- ``pycolmap``: plain pycolmap as a user scripts it: one camera for the
  plate (SIMPLE_RADIAL, the default), ``extract_features``,
  ``match_sequential`` and ``incremental_mapping`` with their defaults;
- ``pycolmap-held``: the same with the true lens (OPENCV, k1 k2) held by
  the mapper (``ba_refine_focal_length`` / ``extra_params`` off);
- ``blender``: Blender's own tracker (libmv, in bpy, headless: a Clip
  Editor area of the background window and ``context.temp_override``):
  the true lens on the clip's tracking camera (held: the tracker refines
  nothing), the solve's two keyframes Blender's defaults (frames 1 and 30;
  ``--blender-keyframes auto``: chosen by Blender, slow on long plates: its
  selection solves from every consecutive pair of its candidates), features
  detected every 12 frames (Harris, threshold 0.002, 40 px apart) and
  tracked forward (affine motion model, pattern 15 px, search 61 px,
  correlation >= 0.75, brute-force pre-pass), tracks under 10 frames
  dropped, camera solved; then tracks whose reprojection error exceeds 2 px
  dropped and the camera solved again from the same keyframes (Blender
  manual's clean-up loop).

Errors: each method's registered cameras are aligned to the truth by a
similarity (rotation: the chordal mean of ``R_est^T R_true`` over the frames,
well posed for a straight dolly where the centres alone leave a roll about
the line free; then scale and offset by least squares on the centres); per
frame the camera-centre error in % of the true path length and the rotation
error (deg); the focal error (%) where the lens is free, with camcal's own sigma of it (the frames' floor: a
focal error below it is as close as the frames determine the focal length).

``--growth``: the first 60 / 120 / 240 / 480 frames of one 480-frame walk,
camcal and plain pycolmap back to back at each size: time and peak memory
per frame, their ratios, camcal's errors; from 200 frames camcal solves the
plate twice, the second time beside a process that keeps one core busy, and
its cameras are compared bit for bit (``--growth-sizes 60,120`` for fewer).

Usage: ``python bench/bench_plates.py`` (comparison at 240 frames and growth:
hours on 2 cores; one 60-frame solve of camcal took 35-70 min on a machine
running 20 processes), ``--quick`` (60 frames, no blur variant, no growth), ``--frames N``,
``--shots walk,loop``, ``--methods camcal,pycolmap``, ``--blender-keyframes auto``, ``--no-growth``,
``--growth`` (growth only), ``--cache DIR`` (renders kept between runs).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")  # numpy's BLAS threads fight for 2 shared cores in the renderer

import cv2  # noqa: E402
import numpy as np  # noqa: E402

from camcal.model.camera import look_at, rotation_angle_deg  # noqa: E402
from camcal.model.distortion import Distortion  # noqa: E402
from camcal.model.rig import Camera, Rig  # noqa: E402
from camcal.synthetic import orbit_set_planes, pixel_rays, procedural_texture, render_planes  # noqa: E402

FPS = 24.0
SIZE = (640, 360)
FIRST = 1001
K_TRUE = np.array([[480.0, 0.0, 322.4], [0.0, 480.0, 178.1], [0.0, 0.0, 1.0]])
LENS = Distortion("polynomial", {"k1": -0.06, "k2": 0.008})
CENTRE = np.array([4.0, 4.0, 0.0])  # the set's centre (orbit_set_planes, extent 8 m)
SHOTS = ("walk", "dolly", "loop", "walk-blur")
METHODS = ("camcal", "camcal-held", "pycolmap", "pycolmap-held", "blender")
GROWTH = (60, 120, 240, 480)
BLUR_SAMPLES = 5
SHUTTER = 0.5  # of the frame interval: a 180 degree shutter
BLENDER_KEYFRAMES = "1,30"  # Blender's own default pair (use_keyframe_selection off)
RENDER_VERSION = 1  # bump when the shots or the renderer change: the cache is keyed by it


def plate_camera() -> Camera:
    """The rendering camera's lens at the identity pose."""
    return Camera("plate", SIZE, K_TRUE, LENS, np.eye(3), np.zeros(3))


def _shake(t: float, seed: int, amplitude: float, frequencies=(0.7, 1.3, 2.1, 3.4)) -> np.ndarray:
    """Three smooth random signals of time (a sum of sines of seeded phases), each of about ``amplitude``."""
    rng = np.random.default_rng(seed)
    phases = rng.uniform(0, 2 * np.pi, (3, len(frequencies)))
    weights = rng.uniform(0.5, 1.0, (3, len(frequencies))) / np.sqrt(len(frequencies))
    return amplitude * np.sum(weights * np.sin(2 * np.pi * np.asarray(frequencies) * t + phases), axis=1)


def _rotate(R: np.ndarray, angles_deg: np.ndarray) -> np.ndarray:
    """``R`` (world -> camera) turned by small angles about the camera's own x, y, z axes."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_euler("xyz", angles_deg, degrees=True).as_matrix() @ R


def shot_pose(shot: str, t: float, n_frames: int) -> tuple[np.ndarray, np.ndarray]:
    """The camera's (R world -> camera, centre) at time ``t`` (seconds) of a shot of ``n_frames`` frames."""
    duration = n_frames / FPS
    if shot == "walk":  # around the set on an ellipse (3.0 x 2.6 m), 0.45 m/s, the head turned inwards
        angle = -2.4 + 0.45 * t / 2.8
        way = np.array([3.0 * np.cos(angle), 2.6 * np.sin(angle), 0.0])
        ahead = np.array([-3.0 * np.sin(angle), 2.6 * np.cos(angle), 0.0])
        ahead /= np.linalg.norm(ahead)
        inwards = -way / np.linalg.norm(way)
        look = np.cos(np.radians(35)) * ahead + np.sin(np.radians(35)) * inwards
        bob = np.array([0.0, 0.0, 0.015 * np.sin(2 * np.pi * 1.8 * t)]) + 0.01 * np.sin(2 * np.pi * 0.9 * t) * np.cross(
            ahead, [0, 0, 1])
        centre = CENTRE + way + [0, 0, 1.6] + bob + _shake(t, 1, 0.01)
        R = look_at(centre, centre + look + [0, 0, -0.25])
        return _rotate(R, _shake(t, 2, 0.5)), centre
    if shot == "dolly":  # 1.5 m along x at 1.3 m from the wall y = 0, panning 30 degrees
        u = t / duration
        centre = np.array([2.6 + 1.5 * u, 1.3, 1.3])
        pan = np.radians(75 - 30 * u)
        return look_at(centre, centre + [np.cos(pan), np.sin(pan), -0.2]), centre
    if shot == "loop":  # a full orbit (radius 2.4 m) around the boxes, back at the start on the last frame
        angle = -2.0 + 2 * np.pi * t / duration * n_frames / max(n_frames - 1, 1)
        centre = CENTRE + [2.4 * np.cos(angle), 2.4 * np.sin(angle), 1.5 + 0.2 * np.sin(angle)]
        return look_at(centre, CENTRE + [0.3 * np.sin(2 * angle), 0.3 * np.cos(angle), 0.6]), centre
    raise ValueError(shot)


def render_shot(folder: Path, shot: str, n_frames: int) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """``folder/plate.1001.png``... and ``folder/truth.json`` (kept when already complete); the truth by frame."""
    truth_file = folder / "truth.json"
    if truth_file.is_file():
        data = json.loads(truth_file.read_text())
        if data.get("version") == RENDER_VERSION and len(data["frames"]) == n_frames:
            return {int(k): (np.array(v["R"]), np.array(v["c"])) for k, v in data["frames"].items()}
    folder.mkdir(parents=True, exist_ok=True)
    base, blur = shot.removesuffix("-blur"), shot.endswith("-blur")
    rng = np.random.default_rng(7)
    planes = orbit_set_planes(rng)
    textures = tuple(procedural_texture(rng) for _ in planes)
    lens = plate_camera()
    rays = pixel_rays(lens)
    offsets = SHUTTER * (np.linspace(-0.5, 0.5, BLUR_SAMPLES) if blur else np.zeros(1))
    truth = {}
    start = time.perf_counter()
    for k in range(n_frames):
        image = np.zeros(SIZE[::-1])
        for offset in offsets:
            R, c = shot_pose(base, (k + offset) / FPS, n_frames)
            image += render_planes(Camera("plate", SIZE, K_TRUE, LENS, R, c), planes, textures, rays)
        cv2.imwrite(str(folder / f"plate.{FIRST + k}.png"), np.round(image / len(offsets)).astype(np.uint8))
        truth[FIRST + k] = shot_pose(base, k / FPS, n_frames)
    truth_file.write_text(json.dumps({"version": RENDER_VERSION, "frames": {
        str(k): {"R": R.tolist(), "c": c.tolist()} for k, (R, c) in truth.items()}}))
    print(f"  rendered {shot} ({n_frames} frames) in {time.perf_counter() - start:.0f} s", flush=True)
    return truth


# -- the methods, each in a child process ---------------------------------------------------------------


def _frame_number(path: str) -> int:
    return int(Path(path).name.split(".")[-2])


def run_camcal(plate: Path, out: Path, held: bool) -> dict:
    import camcal

    kwargs = {}
    if held:
        kwargs["intrinsics"] = Rig(cameras=(plate_camera(),))
    start = time.perf_counter()
    result = camcal.solve(plate / "plate.%04d.png", out / "camcal", matcher="sequential", progress=False, **kwargs)
    seconds = time.perf_counter() - start
    rig = result.rig
    poses = {}
    for frame in rig.frames:
        camera = rig.camera_at_frame("plate", frame.index)
        poses[_frame_number(next(iter(frame.images.values())))] = (camera.R, camera.c)
    camera = rig.camera("plate")
    sigma = (camera.quality or {}).get("sigma", {}).get("fx")  # absent where the lens is held
    return {"seconds": seconds, "poses": poses, "focal": float(camera.K[0, 0]),
            "focal_sigma": None if sigma is None else float(sigma)}


def run_pycolmap(plate: Path, out: Path, held: bool) -> dict:
    import pycolmap

    start = time.perf_counter()
    out.mkdir(parents=True, exist_ok=True)
    database = out / "database.db"
    reader = pycolmap.ImageReaderOptions()
    if held:  # COLMAP's pixel centres are at + 0.5
        reader.camera_model = "OPENCV"
        fx, fy, cx, cy = K_TRUE[0, 0], K_TRUE[1, 1], K_TRUE[0, 2] + 0.5, K_TRUE[1, 2] + 0.5
        reader.camera_params = f"{fx},{fy},{cx},{cy},{LENS.params['k1']},{LENS.params['k2']},0,0"
    pycolmap.extract_features(database, plate, camera_mode=pycolmap.CameraMode.SINGLE, reader_options=reader,
                              device=pycolmap.Device.cpu)
    pycolmap.match_sequential(database, device=pycolmap.Device.cpu)
    options = pycolmap.IncrementalPipelineOptions()
    options.random_seed = 0
    if held:
        options.ba_refine_focal_length = False
        options.ba_refine_extra_params = False
        options.ba_refine_principal_point = False
    (out / "sparse").mkdir(exist_ok=True)
    models = pycolmap.incremental_mapping(database, plate, out / "sparse", options=options)
    seconds = time.perf_counter() - start
    if not models:
        return {"seconds": seconds, "poses": {}, "focal": None}
    reconstruction = max(models.values(), key=lambda r: r.num_reg_images())
    poses = {}
    for image in reconstruction.images.values():
        if image.has_pose:
            pose = image.cam_from_world()
            R = pose.rotation.matrix()
            poses[_frame_number(image.name)] = (R, -R.T @ pose.translation)
    camera = next(iter(reconstruction.cameras.values()))
    return {"seconds": seconds, "poses": poses, "focal": float(camera.focal_length_x)}


def run_blender(plate: Path, out: Path, keyframes: str) -> dict:
    import bpy

    from camcal.blender_bridge import load_addon

    addon = load_addon()
    tracking_lens = __import__(f"{addon.__name__}.tracking", fromlist=["tracking"])
    lens_animation = __import__(f"{addon.__name__}.lens_animation", fromlist=["lens_animation"])
    rigfile = __import__(f"{addon.__name__}.rigfile", fromlist=["rigfile"])
    start = time.perf_counter()
    frames = sorted(plate.glob("plate.*.png"))
    clip = bpy.data.movieclips.load(str(frames[0]))
    clip.frame_start = 1
    n = clip.frame_duration
    scene = bpy.context.scene
    scene.frame_start, scene.frame_end = 1, n
    cam = rigfile.parse_rig(json.loads(Rig(cameras=(plate_camera(),)).to_json())).cameras[0]
    lens = tracking_lens.blender_lens(cam.distortion, cam.K, cam.image_size)
    lens_animation.set_tracking_camera(clip, lens_animation.tracking_key(lens, 36.0))
    tracking = clip.tracking
    settings = tracking.settings
    settings.default_motion_model = "Affine"
    settings.default_pattern_size = 15
    settings.default_search_size = 61
    settings.default_correlation_min = 0.75
    settings.use_default_brute = True
    settings.default_margin = 8
    settings.use_keyframe_selection = keyframes == "auto"
    if keyframes != "auto":
        tracking.objects.active.keyframe_a, tracking.objects.active.keyframe_b = map(int, keyframes.split(","))
    settings.refine_intrinsics_focal_length = False
    settings.refine_intrinsics_principal_point = False
    settings.refine_intrinsics_radial_distortion = False
    window = bpy.context.window_manager.windows[0]
    area = max(window.screen.areas, key=lambda a: a.width * a.height)
    area.type = "CLIP_EDITOR"
    space = area.spaces.active
    space.clip = clip
    region = next(r for r in area.regions if r.type == "WINDOW")
    with bpy.context.temp_override(window=window, screen=window.screen, area=area, region=region, space_data=space,
                                   edit_movieclip=clip):
        for frame in range(1, n, 12):
            scene.frame_set(frame)
            before = {track.name for track in tracking.tracks}
            bpy.ops.clip.select_all(action="DESELECT")
            bpy.ops.clip.detect_features(placement="FRAME", margin=16, threshold=0.002, min_distance=40)
            for track in tracking.tracks:
                track.select = track.name not in before
            bpy.ops.clip.track_markers(backwards=False, sequence=True)
            print(f"frame {frame}: {len(tracking.tracks) - len(before)} tracks detected and tracked, "
                  f"{time.perf_counter() - start:.0f} s", flush=True)
        bpy.ops.clip.select_all(action="SELECT")
        bpy.ops.clip.clean_tracks(frames=10, error=0.0, action="DELETE_TRACK")
        bpy.ops.clip.solve_camera()
        chosen = (tracking.objects.active.keyframe_a, tracking.objects.active.keyframe_b)
        print(f"first solve: keyframes {chosen}, error {tracking.reconstruction.average_error:.3f} px, "
              f"{time.perf_counter() - start:.0f} s", flush=True)
        bpy.ops.clip.select_all(action="SELECT")
        bpy.ops.clip.clean_tracks(frames=0, error=2.0, action="DELETE_TRACK")
        settings.use_keyframe_selection = False  # solve again from the keyframes the first solve used
        bpy.ops.clip.solve_camera()
    seconds = time.perf_counter() - start
    flip = np.diag([1.0, -1.0, -1.0])  # Blender's camera looks down -z with +y up
    poses = {}
    for camera in tracking.reconstruction.cameras:
        matrix = np.array(camera.matrix)
        R_world_from_camera = matrix[:3, :3] / np.linalg.norm(matrix[:3, 0])
        poses[FIRST + camera.frame - 1] = (flip @ R_world_from_camera.T, matrix[:3, 3].copy())
    return {"seconds": seconds, "poses": poses, "focal": float(tracking.camera.focal_length_pixels),
            "tracks": len(tracking.tracks), "blender_error_px": float(tracking.reconstruction.average_error),
            "keyframes": list(chosen)}


def child(method: str, plate: Path, out: Path, result_file: Path, blender_keyframes: str) -> None:
    """Run one method and write its cameras, time and the process's peak memory to ``result_file``."""
    if method.startswith("camcal"):
        result = run_camcal(plate, out, method.endswith("-held"))
    elif method.startswith("pycolmap"):
        result = run_pycolmap(plate, out, method.endswith("-held"))
    else:
        result = run_blender(plate, out, blender_keyframes)
    usage = resource.getrusage(resource.RUSAGE_SELF)
    result["peak_mb"] = usage.ru_maxrss / 1024.0
    result["cpu_seconds"] = usage.ru_utime + usage.ru_stime  # the whole process, imports included
    result["poses"] = {str(k): {"R": np.asarray(R).tolist(), "c": np.asarray(c).tolist()}
                       for k, (R, c) in result["poses"].items()}
    result_file.write_text(json.dumps(result))


def run_method(method: str, plate: Path, work: Path, blender_keyframes: str = BLENDER_KEYFRAMES) -> dict:
    """:func:`child` in a fresh process: its result, or ``{"error": ...}``."""
    out = work / method
    shutil.rmtree(out, ignore_errors=True)
    out.mkdir(parents=True)
    result_file = out / "result.json"
    log = out / "log.txt"
    with open(log, "w") as handle:
        proc = subprocess.run([sys.executable, __file__, "--child", method, str(plate), str(out), str(result_file),
                               blender_keyframes],
                              stdout=handle, stderr=subprocess.STDOUT)
    if proc.returncode != 0 or not result_file.is_file():
        lines = [line for line in log.read_text().splitlines() if line.strip()]
        return {"error": lines[-1] if lines else f"exit {proc.returncode}"}
    result = json.loads(result_file.read_text())
    result["poses"] = {int(k): (np.array(v["R"]), np.array(v["c"])) for k, v in result["poses"].items()}
    return result


# -- errors --------------------------------------------------------------------------------------------


def similarity_errors(poses: dict, truth: dict) -> tuple[np.ndarray, np.ndarray]:
    """Per registered frame: the centre error (% of the true path length) and the rotation error (deg) after
    aligning the estimate to the truth by a similarity (rotation from the cameras' rotations, then scale and
    offset from their centres)."""
    frames = sorted(set(poses) & set(truth))
    R_est = np.array([poses[k][0] for k in frames])
    R_true = np.array([truth[k][0] for k in frames])
    c_est = np.array([poses[k][1] for k in frames])
    c_true = np.array([truth[k][1] for k in frames])
    # world_est = s A world_true + b  =>  R_est A = R_true: A is the chordal mean of R_est^T R_true
    u, _, vt = np.linalg.svd(np.einsum("nji,njk->ik", R_est, R_true))
    A = u @ np.diag([1, 1, np.linalg.det(u @ vt)]) @ vt
    true_offsets = (c_true - c_true.mean(axis=0)) @ A.T
    est_offsets = c_est - c_est.mean(axis=0)
    scale = np.sum(est_offsets * true_offsets) / np.sum(true_offsets ** 2)
    aligned = (est_offsets / scale) @ A + c_true.mean(axis=0)
    every = np.array([truth[k][1] for k in sorted(truth)])
    path = np.sum(np.linalg.norm(np.diff(every, axis=0), axis=1))
    position = 100 * np.linalg.norm(aligned - c_true, axis=1) / path
    rotation = np.array([rotation_angle_deg(Re @ A @ Rt.T) for Re, Rt in zip(R_est, R_true)])
    return position, rotation


def summary(method: str, result: dict, truth: dict) -> dict:
    if "error" in result:
        return {"method": method, "error": result["error"]}
    row = {"method": method, "registered": len(result["poses"]), "frames": len(truth), "seconds": result["seconds"],
           "cpu_seconds": result["cpu_seconds"], "peak_mb": result["peak_mb"]}
    if len(result["poses"]) >= 3:
        position, rotation = similarity_errors(result["poses"], truth)
        row |= {"position_pct": float(position.mean()), "position_max_pct": float(position.max()),
                "position_median_pct": float(np.median(position)), "rotation_deg": float(rotation.mean()),
                "rotation_median_deg": float(np.median(rotation)), "rotation_max_deg": float(rotation.max())}
    if result.get("focal") and not method.endswith("-held") and method != "blender":
        row["focal_pct"] = 100 * (result["focal"] / K_TRUE[0, 0] - 1)
        if result.get("focal_sigma"):
            row["focal_sigma_pct"] = 100 * result["focal_sigma"] / K_TRUE[0, 0]
    return row


def _cell(row: dict, key: str, fmt: str) -> str:
    return format(row[key], fmt) if key in row else "-"


def compare(cache: Path, shots: list[str], n_frames: int, methods: list[str], work: Path,
            blender_keyframes: str = BLENDER_KEYFRAMES) -> list[dict]:
    rows = []
    for shot in shots:
        truth = render_shot(cache / f"{shot}-{n_frames}", shot, n_frames)
        print(f"{shot} ({n_frames} frames):")
        results = {}
        for method in methods:
            results[method] = summary(method, run_method(method, cache / f"{shot}-{n_frames}", work / shot, blender_keyframes),
                                      truth)
            row = results[method]
            if "error" in row:
                print(f"  {method:14s} failed: {row['error']}", flush=True)
                continue
            print(f"  {method:14s} registered {row['registered']:3d}/{row['frames']}, position "
                  f"{_cell(row, 'position_pct', '.3f')} % of path (max {_cell(row, 'position_max_pct', '.3f')}), "
                  f"rotation {_cell(row, 'rotation_deg', '.3f')} deg, focal {_cell(row, 'focal_pct', '+.3f')} %"
                  + (f" (its sigma {row['focal_sigma_pct']:.3f} %)" if "focal_sigma_pct" in row else "")
                  + f", {row['seconds']:.1f} s (process CPU {row['cpu_seconds']:.0f} s), {row['peak_mb']:.0f} MB", flush=True)
        for ours in ("camcal", "camcal-held"):
            peers = [results[m] for m in ("pycolmap", "pycolmap-held", "blender") if m in results]
            if ours not in results or "position_pct" not in results[ours]:
                continue
            mine = results[ours]
            for key in ("position_pct", "rotation_deg"):
                scored = [p[key] for p in peers if key in p and p["registered"] == p["frames"]]
                if scored:
                    print(f"  {ours} / better peer (every frame registered) {key}: {mine[key] / min(scored):.2f}")
            scored = [abs(p["focal_pct"]) for p in peers if "focal_pct" in p and p["registered"] == p["frames"]]
            if scored and "focal_pct" in mine:
                # the floor: how well the frames determine the focal length (camcal's own sigma of it)
                floor = f", the frames determine it to {mine['focal_sigma_pct']:.3f} %" if "focal_sigma_pct" in mine else ""
                print(f"  {ours} / better peer (every frame registered) |focal error|: "
                      f"{abs(mine['focal_pct']) / max(min(scored), 1e-12):.2f}{floor}")
            if "pycolmap" in results and "seconds" in results["pycolmap"]:
                peer = results["pycolmap"]
                print(f"  {ours} / pycolmap time: {mine['seconds'] / peer['seconds']:.2f}, process CPU "
                      f"{mine['cpu_seconds'] / peer['cpu_seconds']:.2f}")
        rows += [dict(row, shot=shot) for row in results.values()]
    return rows


def same_cameras(a: dict, b: dict) -> bool:
    """Whether two runs' cameras are equal bit for bit: the same frames, rotations, centres and focal length."""
    return (a["focal"] == b["focal"] and a["poses"].keys() == b["poses"].keys() and all(
        np.array_equal(a["poses"][k][0], b["poses"][k][0]) and np.array_equal(a["poses"][k][1], b["poses"][k][1])
        for k in a["poses"]))


def growth(cache: Path, work: Path, sizes: tuple[int, ...] = GROWTH, twice_from: int = 200) -> list[dict]:
    """Time and peak memory per frame of camcal and plain pycolmap on the first N frames of one walk, back to back
    (the ratio measured under the same load); camcal's errors at each size; from ``twice_from`` frames camcal
    solves the plate a second time, beside a process that keeps one core busy, and its cameras are compared bit
    for bit.

    The walk's poses do not depend on the shot's length, so the first N frames of the longest render are the
    N-frame walk."""
    longest = max(sizes)
    full = cache / f"walk-{longest}"
    truth = render_shot(full, "walk", longest)
    rows = []
    print(f"cost growth (the first N frames of one {longest}-frame walk; camcal then plain pycolmap, back to back):")
    for n in sizes:
        plate = cache / f"walk-{longest}-first{n}"
        if not plate.is_dir():
            plate.mkdir()
            for k in range(n):
                os.link(full / f"plate.{FIRST + k}.png", plate / f"plate.{FIRST + k}.png")
        first = {k: truth[k] for k in range(FIRST, FIRST + n)}
        results = {}
        for method in ("camcal", "pycolmap"):
            result = run_method(method, plate, work / f"growth-{n}")
            if "error" in result:
                print(f"  {n:4d} frames {method:9s} failed: {result['error']}", flush=True)
                continue
            results[method] = result
            row = summary(method, result, first)
            rows.append(dict(row, frames=n, growth=True))
            print(f"  {n:4d} frames {method:9s} registered {len(result['poses']):3d}, {result['seconds']:7.1f} s "
                  f"({1000 * result['seconds'] / n:.0f} ms/frame; process CPU {result['cpu_seconds']:.0f} s), "
                  f"peak {result['peak_mb']:.0f} MB ({result['peak_mb'] / n:.2f} MB/frame), position "
                  f"{_cell(row, 'position_pct', '.4f')} % of path, rotation {_cell(row, 'rotation_deg', '.4f')} deg, "
                  f"focal {_cell(row, 'focal_pct', '+.3f')} %", flush=True)
        if len(results) == 2:
            mine, peer = results["camcal"], results["pycolmap"]
            print(f"  {n:4d} frames camcal / pycolmap: time {mine['seconds'] / peer['seconds']:.2f}, process CPU "
                  f"{mine['cpu_seconds'] / peer['cpu_seconds']:.2f}, peak memory {mine['peak_mb'] / peer['peak_mb']:.2f}",
                  flush=True)
        if n >= twice_from and "camcal" in results:
            # beside a busy process: the threads of the second run are scheduled otherwise than the first's
            busy = subprocess.Popen([sys.executable, "-c", "while True: pass"])
            try:
                again = run_method("camcal", plate, work / f"growth-{n}-again")
            finally:
                busy.kill()
                busy.wait()
            same = "error" not in again and same_cameras(results["camcal"], again)
            rows.append({"frames": n, "growth": True, "method": "camcal-twice", "same_bit_for_bit": same})
            print(f"  {n:4d} frames camcal solved again beside a busy process: the same cameras bit for bit: "
                  f"{'yes' if same else 'NO'}", flush=True)
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cache", type=Path, help="keep the renders here between runs (default: a temporary folder)")
    parser.add_argument("--frames", type=int, default=240, help="frames per shot (default 240)")
    parser.add_argument("--quick", action="store_true", help="60 frames, no blur variant, no growth")
    parser.add_argument("--shots", default=",".join(SHOTS), help=f"comma-separated, of {', '.join(SHOTS)}")
    parser.add_argument("--methods", default=",".join(METHODS), help=f"comma-separated, of {', '.join(METHODS)}")
    parser.add_argument("--growth", action="store_true", help="only the cost growth")
    parser.add_argument("--no-growth", action="store_true", help="only the comparison")
    parser.add_argument("--growth-sizes", default=",".join(map(str, GROWTH)),
                        help="comma-separated frame counts of the growth (default %(default)s)")
    parser.add_argument("--json", type=Path, help="also write every row here")
    parser.add_argument("--blender-keyframes", default=BLENDER_KEYFRAMES,
                        help="Blender's two keyframes A,B, or auto (chosen by Blender: slow on long plates; "
                             "default %(default)s, Blender's own)")
    parser.add_argument("--child", nargs=5, help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.child:
        method, plate, out, result_file, blender_keyframes = args.child
        child(method, Path(plate), Path(out), Path(result_file), blender_keyframes)
        return
    shots = [s for s in args.shots.split(",") if s]
    frames = args.frames
    if args.quick:
        frames, shots = 60, [s for s in shots if not s.endswith("-blur")]
    with tempfile.TemporaryDirectory(prefix="bench_plates_") as tmp:
        cache = args.cache or Path(tmp) / "renders"
        cache.mkdir(parents=True, exist_ok=True)
        rows = []
        if not args.growth:
            rows += compare(cache, shots, frames, [m for m in args.methods.split(",") if m], Path(tmp) / "work",
                            args.blender_keyframes)
        if not args.quick and not args.no_growth:
            rows += growth(cache, Path(tmp) / "work", tuple(int(n) for n in args.growth_sizes.split(",") if n))
        if args.json:
            args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
