"""The panel's ``camcal.solve_clip``: camcal solves a Movie Clip in a subprocess, the camera lands in the scene.

The fast tests run the operator and its job against a stand-in ``camcal``
(a small script that prints camcal's stage lines, builds its output the way
camcal does, beside the target under a temporary name, and writes a rig the
test chose); the slow test runs the real ``camcal solve`` on a rendered plate
and measures the scene's camera against the rendering's.
"""

import json
import os
import shutil
import signal
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from addon_helpers import blender_project, camera_dict, frame, rotation, write_rig
from addon_helpers import addon, bpy  # noqa: F401  (fixtures)
from camcal.cli import build_parser
from camcal.model.rig import Camera, Rig

ROOT = Path(__file__).resolve().parents[2]
FIRST = 1001
SIZE = (64, 48)
K = [[60.0, 0.0, 31.5], [0.0, 60.0, 23.5], [0.0, 0.0, 1.0]]

# A stand-in for camcal: records its arguments, prints two stage lines, builds OUT's files in
# ".OUT.camcal-tmp.XXXXXXXX" and moves them into OUT (removing it on an interruption, as camcal's
# atomic output does); FAKE_CAMCAL_MODE: solve, fail, hang (waits), stubborn (waits and ignores SIGINT).
FAKE_CAMCAL = """\
import json, os, shutil, signal, sys, time
args = sys.argv[1:]
out = os.path.abspath(args[args.index("--out") + 1])
with open(os.environ["FAKE_CAMCAL_ARGV"], "w") as handle:
    json.dump(args, handle)
mode = os.environ.get("FAKE_CAMCAL_MODE", "solve")
if mode == "stubborn":
    signal.signal(signal.SIGINT, signal.SIG_IGN)
if mode == "fail":
    print("camcal: error: frame 1002 of plate.%04d.png is missing", file=sys.stderr)
    sys.exit(2)
staging = os.path.join(os.path.dirname(out), "." + os.path.basename(out) + ".camcal-tmp.k1ll3d00")
os.makedirs(staging)
open(os.path.join(staging, "database.db"), "wb").close()
try:
    for stage in ("extracting features from 3 images", "matching (sequential)"):
        print("camcal solve: " + stage, file=sys.stderr, flush=True)
    if mode in ("hang", "stubborn"):
        time.sleep(120)
    shutil.copy(os.environ["FAKE_CAMCAL_RIG"], os.path.join(staging, "solve.rig.json"))
    os.makedirs(out, exist_ok=True)
    for name in os.listdir(staging):
        os.replace(os.path.join(staging, name), os.path.join(out, name))
finally:
    shutil.rmtree(staging, ignore_errors=True)
print(json.dumps({"figures": {"n_images": 3, "n_registered": 3, "rms_px": 0.25},
                  "files": [{"path": os.path.join(out, "solve.rig.json"), "kind": "rig"}]}))
"""


def _executable(folder, body):
    """``folder/camcal``: a Python script run by this interpreter."""
    folder.mkdir(exist_ok=True)
    path = folder / "camcal"
    path.write_text(f"#!{sys.executable}\n{body}")
    path.chmod(0o755)
    return path


@pytest.fixture
def fake_camcal(tmp_path, monkeypatch):
    """The stand-in ``camcal`` first on the PATH; returns a function choosing the rig it writes."""
    _executable(tmp_path / "bin", FAKE_CAMCAL)
    monkeypatch.setenv("PATH", f"{tmp_path / 'bin'}{os.pathsep}{os.environ['PATH']}")
    monkeypatch.setenv("FAKE_CAMCAL_ARGV", str(tmp_path / "argv.json"))
    monkeypatch.setenv("FAKE_CAMCAL_MODE", "solve")

    def rig(shift=0.0, k1=-0.08, name="known"):
        cam = camera_dict("plate", SIZE, K, distortion={"model": "polynomial", "params": {"k1": k1, "k2": 0.0}})
        frames = [frame(k, rotation(0.05 * k, -0.1 * k, 0.02), (0.2 * k + shift, 0.1, -0.05 * k)) for k in range(3)]
        path = write_rig(tmp_path / f"{name}.rig.json", [cam], frames)
        monkeypatch.setenv("FAKE_CAMCAL_RIG", str(path))
        return Rig.load(path)

    return rig


def _plates(folder, n=3):
    """``folder/plate.1001.png``...: an image sequence of grey frames."""
    import cv2

    folder.mkdir()
    for index in range(n):
        cv2.imwrite(str(folder / f"plate.{FIRST + index}.png"), np.full((SIZE[1], SIZE[0]), 40 * index + 60, np.uint8))
    return folder


@pytest.fixture
def registered(bpy, addon):
    addon.register()
    yield bpy
    addon.unregister()


# -- the command, without Blender -----------------------------------------------------------------------


def test_the_command_is_camcal_solve_on_the_clip_frames(addon, tmp_path):
    import importlib

    job = importlib.import_module(f"{addon.__name__}.solvejob")
    assert job.sequence_pattern("/plates/shot_a.v2.1001.exr") == ("shot_a.v2.%04d.exr", 1001)
    assert job.camera_name("shot A.1001.exr") == "shot_A"
    with pytest.raises(job.SolveError, match="no frame number"):
        job.sequence_pattern("/plates/still.png")
    sequence = job.ClipSource(str(tmp_path / "plate.0998.exr"), "SEQUENCE", 998, 5, "plate")
    movie = job.ClipSource(str(tmp_path / "shot.mov"), "MOVIE", 0, 240, "shot")
    parser = build_parser()
    args = parser.parse_args(job.solve_command("camcal", sequence, str(tmp_path / "out"), features=512)[1:])
    # camcal's own parser reads what the add-on writes: the plate, its frames, JSON on stdout
    assert args.folders == [str(tmp_path)] and args.camera == {"plate": "plate.%04d.exr"}
    assert args.frames == "998-1002" and args.features == 512 and args.matcher == "sequential" and args.json
    args = parser.parse_args(job.solve_command("camcal", movie, str(tmp_path / "o"), model="division")[1:])
    assert args.camera == {"shot": "shot.mov"} and args.frames is None and args.model == "division"
    assert job.stage_fraction("camcal solve: matching (sequential)") == pytest.approx(1 / len(job.STAGES))
    assert job.stage_fraction("registered 3 / 3 images", 0.5) == 0.5
    with pytest.raises(job.SolveError, match="not found or not executable"):
        job.find_camcal(str(tmp_path / "nothing"))


# -- the job: progress and cancel, against the stand-in ------------------------------------------------


def _wait_for(condition, timeout_s=20.0):
    deadline = time.monotonic() + timeout_s
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.02)


@pytest.fixture
def sigint_handled():
    """SIGINT handled in this process while the test runs: a test run started in the background by a shell ignores
    SIGINT, and so would the run the job starts (an ignored signal stays ignored across exec; a handled one is reset
    to the default): the run then gets the disposition it has under an interactive Blender."""
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    yield
    signal.signal(signal.SIGINT, previous)


@pytest.mark.parametrize("mode", ["hang", "stubborn"])
def test_cancel_stops_camcal_and_leaves_nothing(addon, fake_camcal, tmp_path, monkeypatch, sigint_handled, mode):
    """hang cleans up on SIGINT as camcal does; stubborn ignores it: killed after the grace time, its staging
    folder removed by the job."""
    import importlib

    job_module = importlib.import_module(f"{addon.__name__}.solvejob")
    monkeypatch.setenv("FAKE_CAMCAL_MODE", mode)
    fake_camcal()
    plates = _plates(tmp_path / "plates")
    before = sorted(os.listdir(plates))
    source = job_module.ClipSource(str(plates / f"plate.{FIRST}.png"), "SEQUENCE", FIRST, 3, "plate")
    out = plates / "camcal_solve" / "plate"
    # hang's grace long enough for a loaded machine to run its clean-up (it ends as soon as that is done);
    # stubborn waits the whole grace out
    grace_s = 1.0 if mode == "stubborn" else 30.0
    job = job_module.SolveJob(job_module.solve_command(shutil.which("camcal"), source, str(out)), str(out),
                              grace_s=grace_s)
    job.start()
    _wait_for(lambda: job.last_line == "matching (sequential)")
    assert job.fraction == pytest.approx(1 / len(job_module.STAGES)) and not job.poll()
    assert "matching (sequential)" in job.status_text() and (plates / "camcal_solve").is_dir()
    job.cancel()
    assert job.returncode is not None  # ended and reaped
    assert (job.returncode == -signal.SIGKILL) == (mode == "stubborn")
    assert sorted(os.listdir(plates)) == before  # no output, no staging folder, no camcal_solve folder


# -- the operator --------------------------------------------------------------------------------------


def _scene_counts(bpy):
    return (len({o for s in bpy.data.scenes for o in s.objects}), len(bpy.data.scenes), len(bpy.data.movieclips),
            len(bpy.data.collections))


def test_operator_solves_the_clip_and_imports_the_camera(registered, addon, fake_camcal, tmp_path):
    bpy = registered
    known = fake_camcal()
    plates = _plates(tmp_path / "plates")
    clip = bpy.data.movieclips.load(str(plates / f"plate.{FIRST}.png"))
    clip.frame_start = 10
    scene = bpy.context.scene
    scene.active_clip = clip
    assert bpy.ops.camcal.solve_clip(features=512, compositor=False) == {"FINISHED"}
    argv = json.loads((tmp_path / "argv.json").read_text())
    assert argv[:6] == ["solve", str(plates), "--images", "plate=plate.%04d.png", "--frames", f"{FIRST}-{FIRST + 2}"]
    out = plates / "camcal_solve" / "plate"
    assert sorted(os.listdir(plates / "camcal_solve")) == ["plate"] and (out / "solve.rig.json").is_file()
    assert not [path for path in tmp_path.rglob("*") if "camcal-tmp" in path.name]

    obj = scene.camera
    assert obj.name == "solve_plate" and (scene.frame_start, scene.frame_end) == (10, 12)
    X = np.random.default_rng(3).uniform([-1, -1, 3], [1, 1, 6], (20, 3))
    for k in range(3):  # rig frame k on the scene frame that shows the clip's k-th frame
        scene.frame_set(10 + k)
        truth = known.camera_at_frame("plate", k)
        Xk = truth.R.T @ (X.T) + truth.c[:, None]  # points in front of this camera
        reference = truth.K @ (truth.R @ (Xk - truth.c[:, None]))
        np.testing.assert_allclose(blender_project(bpy, obj, scene, Xk.T), (reference[:2] / reference[2]).T, atol=1e-3)
    # the clip carries the solved lens (as the add-on maps camcal's lens) and is the camera's background
    lens = addon.tracking.blender_lens(addon.rigfile.Distortion("polynomial", {"k1": -0.08, "k2": 0.0}), K, SIZE,
                                       (0, 0))
    tc = clip.tracking.camera
    assert tc.distortion_model == lens.distortion_model == "POLYNOMIAL"
    assert tc.focal_length_pixels == pytest.approx(60.0) and tc.k1 == pytest.approx(lens.params["k1"])
    assert tuple(tc.principal_point_pixels) == pytest.approx(lens.principal_point_pixels)
    background = obj.data.background_images[0]
    assert background.source == "MOVIE_CLIP" and background.clip == clip and scene.active_clip == clip
    assert [c.name for c in bpy.data.movieclips] == [clip.name]  # no second clip of the plate

    # solved again (the camera moved, another lens): the same objects, updated in place
    counts = _scene_counts(bpy)
    known = fake_camcal(shift=0.5, k1=-0.02, name="again")
    assert bpy.ops.camcal.solve_clip(features=512, compositor=False) == {"FINISHED"}
    assert _scene_counts(bpy) == counts and scene.camera.name == "solve_plate"
    scene.frame_set(11)
    np.testing.assert_allclose(scene.camera.matrix_world.translation, known.camera_at_frame("plate", 1).c, atol=1e-5)
    assert clip.tracking.camera.k1 == pytest.approx(-0.02) and bpy.data.movieclips[:] == [clip]


def test_a_movie_clip_is_solved_whole_at_its_frame_rate(registered, fake_camcal, tmp_path):
    import cv2

    bpy = registered
    known = fake_camcal()
    (tmp_path / "shot").mkdir()
    movie = cv2.VideoWriter(str(tmp_path / "shot" / "take 2.avi"), cv2.VideoWriter_fourcc(*"MJPG"), 25.0, SIZE)
    for index in range(3):
        movie.write(np.full((SIZE[1], SIZE[0], 3), 40 * index + 60, np.uint8))
    movie.release()
    clip = bpy.data.movieclips.load(str(tmp_path / "shot" / "take 2.avi"))
    clip.frame_start, clip.frame_offset = 101, 1  # the clip's second frame shows on frame 101
    assert bpy.ops.camcal.solve_clip(clip=clip.name, compositor=False) == {"FINISHED"}
    argv = json.loads((tmp_path / "argv.json").read_text())
    assert argv[:4] == ["solve", str(tmp_path / "shot"), "--images", "take_2=take 2.avi"] and "--frames" not in argv
    scene = bpy.context.scene
    assert (scene.render.fps, scene.render.fps_base) == (25, 1.0) and (scene.frame_start, scene.frame_end) == (100, 102)
    scene.frame_set(101)  # the clip's frame 1, the rig's frame index 1
    np.testing.assert_allclose(scene.camera.matrix_world.translation, known.camera_at_frame("plate", 1).c, atol=1e-6)
    assert (tmp_path / "shot" / "camcal_solve" / "take_2" / "solve.rig.json").is_file()


def _modal_stand_in(bpy, clip, job):
    """The operator's modal methods on a stand-in instance: background Blender has no event loop to drive them
    (there ``invoke`` runs ``execute``), so the test sends the events; the timer and progress are Blender's."""
    operator = bpy.types.CAMCAL_OT_solve_clip

    class StandIn:
        modal, cancel, _status, _end_ui, _finish = (operator.modal, operator.cancel, operator._status,
                                                    operator._end_ui, operator._finish)
        up_axis, compositor, _clip_name, _frame_start = "Z", False, clip.name, clip.frame_start

        def __init__(self):
            self.reports, self._job = [], job
            self._timer = bpy.context.window_manager.event_timer_add(0.25, window=bpy.context.window)
            bpy.context.window_manager.progress_begin(0, 100)

        def report(self, kinds, message):
            self.reports.append((set(kinds), message))

    return StandIn()


@pytest.mark.parametrize("mode", ["hang", "solve"])
def test_modal_operator_polls_on_timer_and_cancels_on_esc(registered, addon, fake_camcal, tmp_path, monkeypatch,
                                                          mode):
    import importlib
    from types import SimpleNamespace

    bpy = registered
    job_module = importlib.import_module(f"{addon.__name__}.solvejob")
    monkeypatch.setenv("FAKE_CAMCAL_MODE", mode)
    fake_camcal()
    plates = _plates(tmp_path / "plates")
    before = sorted(os.listdir(plates))
    clip = bpy.data.movieclips.load(str(plates / f"plate.{FIRST}.png"))
    source = job_module.ClipSource(str(plates / f"plate.{FIRST}.png"), "SEQUENCE", FIRST, 3, "plate")
    out = plates / "camcal_solve" / "plate"
    job = job_module.SolveJob(job_module.solve_command(shutil.which("camcal"), source, str(out)), str(out))
    job.start()
    operator = _modal_stand_in(bpy, clip, job)
    timer, esc = SimpleNamespace(type="TIMER", value="NOTHING"), SimpleNamespace(type="ESC", value="PRESS")
    assert operator.modal(bpy.context, SimpleNamespace(type="MOUSEMOVE", value="NOTHING")) == {"PASS_THROUGH"}
    if mode == "hang":
        _wait_for(lambda: job.last_line == "matching (sequential)")
        assert operator.modal(bpy.context, timer) == {"PASS_THROUGH"} and job.returncode is None
        assert operator.modal(bpy.context, esc) == {"CANCELLED"}
        assert job.returncode is not None and sorted(os.listdir(plates)) == before and not bpy.data.objects
        assert operator.reports == [({"INFO"}, "camcal solve cancelled: nothing was written")]
        return
    _wait_for(lambda: job.process.poll() is not None)
    assert operator.modal(bpy.context, timer) == {"FINISHED"}
    assert bpy.context.scene.camera.name == "solve_plate" and operator.reports[-1][0] == {"INFO"}


def test_a_failed_solve_is_camcal_error_line_and_imports_nothing(registered, fake_camcal, tmp_path, monkeypatch):
    bpy = registered
    monkeypatch.setenv("FAKE_CAMCAL_MODE", "fail")
    clip = bpy.data.movieclips.load(str(_plates(tmp_path / "plates") / f"plate.{FIRST}.png"))
    bpy.context.scene.active_clip = clip
    with pytest.raises(RuntimeError, match=r"frame 1002 of plate.%04d.png is missing"):
        bpy.ops.camcal.solve_clip()
    assert not bpy.data.objects and sorted(os.listdir(tmp_path / "plates")) == [
        f"plate.{FIRST + k}.png" for k in range(3)]
    (tmp_path / "a file").write_text("")
    with pytest.raises(RuntimeError, match="cannot make the solve folder .*a file"):
        bpy.ops.camcal.solve_clip(output_directory=str(tmp_path / "a file" / "solves"))
    monkeypatch.setenv("PATH", str(tmp_path / "nowhere"))
    with pytest.raises(RuntimeError, match="camcal was not found on the PATH"):
        bpy.ops.camcal.solve_clip()


# -- the real camcal on a rendered plate ------------------------------------------------------------------


@pytest.mark.slow
def test_operator_solves_a_rendered_plate_to_the_true_cameras(registered, tmp_path, monkeypatch):
    """The fast siblings above run the operator against a stand-in camcal; this one runs camcal itself."""
    import importlib

    import cv2

    from camcal.model.camera import look_at, rotation_angle_deg, similarity_Umeyama1991
    from camcal.model.distortion import Distortion
    from camcal.synthetic import procedural_texture, render_planes, room_corner_planes

    bpy = registered
    width, height, n_frames, focal = 256, 192, 6, 200.0
    K_true = np.array([[focal, 0.0, (width - 1) / 2], [0.0, focal, (height - 1) / 2], [0.0, 0.0, 1.0]])
    rng = np.random.default_rng(0)
    textures = tuple(procedural_texture(rng) for _ in range(3))
    (tmp_path / "plates").mkdir()
    truth = {}
    target = np.array([1.5, 1.5, 1.0])
    for k in range(n_frames):  # an arc around the room corner (a straight walk leaves the alignment's roll free)
        angle = np.radians(30.0 + 6.0 * k)
        centre = target + [4.7 * np.cos(angle), 4.7 * np.sin(angle), 0.6 + 0.05 * k]
        truth[k] = Camera("plate", (width, height), K_true, Distortion("polynomial", {"k1": -0.05, "k2": 0.0}),
                          look_at(centre, target + [0.1 * k, 0.0, 0.0]), centre)
        cv2.imwrite(str(tmp_path / "plates" / f"plate.{FIRST + k}.png"),
                    render_planes(truth[k], room_corner_planes(), textures))
    _executable(tmp_path / "bin", "import sys\nfrom camcal.cli import main\nsys.exit(main())\n")
    monkeypatch.setenv("PATH", f"{tmp_path / 'bin'}{os.pathsep}{os.environ['PATH']}")
    monkeypatch.setenv("PYTHONPATH", os.pathsep.join(filter(None, [str(ROOT), os.environ.get("PYTHONPATH")])))

    clip = bpy.data.movieclips.load(str(tmp_path / "plates" / f"plate.{FIRST}.png"))
    scene = bpy.context.scene
    scene.active_clip = clip
    assert bpy.ops.camcal.solve_clip(features=1024, matcher="exhaustive", compositor=False) == {"FINISHED"}
    obj = scene.camera
    solved = {}
    for k in range(n_frames):
        scene.frame_set(clip.frame_start + k)
        M = np.array(obj.matrix_world)
        solved[k] = (np.diag([1.0, -1.0, -1.0]) @ M[:3, :3].T, M[:3, 3])  # camcal's R (world -> camera), c
    rig = Rig.load(tmp_path / "plates" / "camcal_solve" / "plate" / "solve.rig.json")
    for k, (R, c) in solved.items():  # the scene holds camcal's solve (float32 in Blender)
        np.testing.assert_allclose(c, rig.camera_at_frame("plate", k).c, atol=1e-5)
        np.testing.assert_allclose(R, rig.camera_at_frame("plate", k).R, atol=1e-5)
    s, R_align, t = similarity_Umeyama1991(np.array([solved[k][1] for k in solved]),
                                           np.array([truth[k].c for k in solved]))
    path_length = sum(np.linalg.norm(truth[k + 1].c - truth[k].c) for k in range(n_frames - 1))
    for k, (R, c) in solved.items():
        # measured: 1 mm (0.05 % of the 2.5 m path) and 0.26 deg, most of it the principal point's 0.6 px in y
        # (six frames of a 256 px plate determine it to a few tenths of a pixel)
        assert np.linalg.norm(s * R_align @ c + t - truth[k].c) < 0.005 * path_length
        assert rotation_angle_deg(truth[k].R @ (R @ R_align.T).T) < 0.5
    assert clip.tracking.camera.focal_length_pixels == pytest.approx(focal, rel=0.01)

    # Esc on the real camcal: stopped mid-run, nothing of it left
    job_module = importlib.import_module(f"{bpy.types.CAMCAL_OT_solve_clip.__module__.rsplit('.', 1)[0]}.solvejob")
    before = sorted(os.listdir(tmp_path / "plates"))
    source = job_module.ClipSource(str(tmp_path / "plates" / f"plate.{FIRST}.png"), "SEQUENCE", FIRST, n_frames, "p")
    out = tmp_path / "plates" / "cancelled"
    command = job_module.solve_command(shutil.which("camcal"), source, str(out), features=1024)
    job = job_module.SolveJob(command, str(out))
    job.start()
    _wait_for(lambda: job.fraction > 0, timeout_s=120)
    job.cancel()
    assert job.returncode is not None and sorted(os.listdir(tmp_path / "plates")) == before
