"""Matchmove of real footage with a known lens: camcal solve against plain pycolmap, both given the same intrinsics.

Data: sequences in the KITTI odometry layout (a folder each: ``image_l/``
or ``image_0/`` with the frames ``000000.png``..., ``calib.txt`` whose first
line is the left camera's 3x4 projection ``P0`` (``fx 0 cx 0 0 fy cy 0 0 0 1
0``, an optional ``P0:`` label), ``poses.txt`` with one 3x4 camera-to-world
pose per frame). Rectified frames: no lens distortion. The folder named by
``CAMCAL_REAL_PLATE_DIR`` is one such sequence or holds several. A public
51-frame excerpt of a KITTI odometry sequence (1226 x 370, forward driving,
about 1.2 m per frame) ships as ``KITTI_sequence_1`` in the GitHub
repositories Gongsta/vSLAM-py and dawn-mathew/Visual-Odometry-KITTI-Sequence,
the second also with ``KITTI_sequence_2`` (51 frames, 1241 x 376, driving
through a bend); KITTI's frames and poses are the KITTI Vision Benchmark's
(Geiger, Lenz & Urtasun 2012, CC BY-NC-SA 3.0), not camcal's to ship.

Methods, on the same frames, the lens held at ``P0``'s intrinsics:

- ``camcal``: ``camcal.solve`` with ``matcher="sequential"`` and
  ``intrinsics=`` a rig of that camera (the lens held), every other option
  its default;
- ``pycolmap``: plain pycolmap as a user scripts it: one PINHOLE camera with
  ``P0``'s intrinsics (COLMAP's pixel centres at + 0.5), ``extract_features``,
  ``match_sequential`` and ``incremental_mapping`` with their defaults and
  the intrinsics held (``ba_refine_*`` off);
- ``pycolmap-forward``: the same database mapped again with
  ``init_max_forward_motion = 1`` (COLMAP's mapper otherwise refuses every
  first pair that moves along its view, which a driving shot's pairs all do;
  camcal's mapper makes the same retry): the time is extraction and matching
  plus this mapping.

Errors: each method's cameras aligned to the ground truth by a similarity
(:func:`bench_plates.similarity_errors`): per frame the camera-centre error
in % of the true path length and the rotation error (deg).

Usage: ``CAMCAL_REAL_PLATE_DIR=DIR python bench/bench_real_plate.py``
(``--methods camcal,pycolmap``, ``--json FILE``).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_plates import _cell, similarity_errors  # noqa: E402

from camcal.model.distortion import Distortion  # noqa: E402
from camcal.model.rig import Camera, Rig  # noqa: E402

ENV = "CAMCAL_REAL_PLATE_DIR"
METHODS = ("camcal", "pycolmap", "pycolmap-forward")


@dataclass(frozen=True)
class Sequence:
    """One KITTI-layout sequence: its frames' folder, the left camera (identity pose) and the true poses."""

    name: str
    frames: Path
    camera: Camera
    truth: dict[int, tuple[np.ndarray, np.ndarray]]


def load_sequence(folder: Path) -> Sequence:
    """A KITTI-layout sequence: ``image_l`` (or ``image_0``), ``calib.txt``'s ``P0``, ``poses.txt``.

    ``poses.txt``'s line k is frame k's ``[R_wc | c]`` (camera to world): world -> camera is ``R_wc^T``.
    """
    frames = next((folder / name for name in ("image_l", "image_0") if (folder / name).is_dir()), None)
    if frames is None:
        raise FileNotFoundError(f"{folder}: no image_l/ or image_0/ folder of frames")
    first = (folder / "calib.txt").read_text().splitlines()[0].split()
    P0 = np.array([float(v) for v in (first[1:] if first[0].endswith(":") else first)]).reshape(3, 4)
    paths = sorted(frames.glob("*.png"))
    image = cv2.imread(str(paths[0]), cv2.IMREAD_GRAYSCALE)
    camera = Camera("image_l", (image.shape[1], image.shape[0]), P0[:, :3], Distortion("none", {}), np.eye(3),
                    np.zeros(3))
    truth = {}
    for k, line in enumerate((folder / "poses.txt").read_text().split("\n")):
        if line.strip():
            pose = np.array([float(v) for v in line.split()]).reshape(3, 4)
            truth[k] = (pose[:, :3].T, pose[:, 3].copy())
    numbers = [int(path.stem) for path in paths]
    missing = sorted(set(numbers) - set(truth))
    if missing:
        raise ValueError(f"{folder}: frames {missing[:5]} have no pose in poses.txt")
    return Sequence(folder.name, frames, camera, {k: truth[k] for k in numbers})


def sequences(root: Path) -> list[Sequence]:
    """The sequences under ``root``: itself when it is one, else its sub-folders that are."""
    def is_sequence(folder: Path) -> bool:
        return (folder / "calib.txt").is_file() and (folder / "poses.txt").is_file()

    if is_sequence(root):
        return [load_sequence(root)]
    return [load_sequence(folder) for folder in sorted(root.iterdir()) if folder.is_dir() and is_sequence(folder)]


def run_camcal(sequence: Sequence, out: Path) -> dict:
    """camcal solve with the lens held: its cameras by frame number, the seconds and its notes."""
    import camcal

    start = time.perf_counter()
    result = camcal.solve(sequence.frames / "%06d.png", out, matcher="sequential",
                          intrinsics=Rig(cameras=(sequence.camera,)), progress=False)
    seconds = time.perf_counter() - start
    rig = result.rig
    poses = {}
    for frame in rig.frames:
        camera = rig.camera_at_frame(sequence.camera.name, frame.index)
        poses[int(Path(frame.images[sequence.camera.name]).stem)] = (camera.R, camera.c)
    return {"seconds": seconds, "poses": poses, "notes": list(result.sfm.notes)}


def run_pycolmap(sequence: Sequence, out: Path) -> dict[str, dict]:
    """Plain pycolmap with the intrinsics held; then the same database mapped allowing a forward first pair."""
    import pycolmap

    K = sequence.camera.K
    out.mkdir(parents=True, exist_ok=True)
    database = out / "database.db"
    start = time.perf_counter()
    reader = pycolmap.ImageReaderOptions()
    reader.camera_model = "PINHOLE"  # COLMAP's pixel centres are at + 0.5
    reader.camera_params = f"{K[0, 0]},{K[1, 1]},{K[0, 2] + 0.5},{K[1, 2] + 0.5}"
    pycolmap.extract_features(database, sequence.frames, camera_mode=pycolmap.CameraMode.SINGLE,
                              reader_options=reader, device=pycolmap.Device.cpu)
    pycolmap.match_sequential(database, device=pycolmap.Device.cpu)
    shared = time.perf_counter() - start
    results = {}
    for method, forward in (("pycolmap", False), ("pycolmap-forward", True)):
        start = time.perf_counter()
        options = pycolmap.IncrementalPipelineOptions()
        options.random_seed = 0
        options.ba_refine_focal_length = options.ba_refine_extra_params = False
        options.ba_refine_principal_point = False
        if forward:
            options.mapper.init_max_forward_motion = 1.0
        sparse = out / f"sparse-{method}"
        sparse.mkdir()
        models = pycolmap.incremental_mapping(database, sequence.frames, sparse, options=options)
        seconds = shared + time.perf_counter() - start
        poses = {}
        if models:
            reconstruction = max(models.values(), key=lambda r: r.num_reg_images())
            for image in reconstruction.images.values():
                if image.has_pose:
                    pose = image.cam_from_world()
                    R = pose.rotation.matrix()
                    poses[int(Path(image.name).stem)] = (R, -R.T @ pose.translation)
        results[method] = {"seconds": seconds, "poses": poses}
    return results


def score(method: str, result: dict, truth: dict) -> dict:
    """Registered frames, mean / max position error (% of path), mean rotation error (deg), seconds."""
    row = {"method": method, "registered": len(result["poses"]), "frames": len(truth), "seconds": result["seconds"]}
    if len(result["poses"]) >= 3:
        position, rotation = similarity_errors(result["poses"], truth)
        row |= {"position_pct": float(position.mean()), "position_max_pct": float(position.max()),
                "rotation_deg": float(rotation.mean()), "rotation_max_deg": float(rotation.max())}
    return row


def compare(sequence: Sequence, methods: list[str], work: Path) -> list[dict]:
    """Every method on one sequence: its rows, printed as they come."""
    path = np.sum(np.linalg.norm(np.diff([sequence.truth[k][1] for k in sorted(sequence.truth)], axis=0), axis=1))
    print(f"{sequence.name}: {len(sequence.truth)} frames {sequence.camera.image_size[0]}x"
          f"{sequence.camera.image_size[1]}, fx {sequence.camera.K[0, 0]:.1f} px, path {path:.1f} m", flush=True)
    results = {}
    if "camcal" in methods:
        results["camcal"] = run_camcal(sequence, work / "camcal")
        for note in results["camcal"]["notes"]:
            print(f"  camcal: {note}")
    if any(method.startswith("pycolmap") for method in methods):
        results |= {m: r for m, r in run_pycolmap(sequence, work / "pycolmap").items() if m in methods}
    rows = []
    for method in methods:
        row = score(method, results[method], sequence.truth)
        rows.append(dict(row, sequence=sequence.name))
        print(f"  {method:17s} registered {row['registered']:3d}/{row['frames']}, position "
              f"{_cell(row, 'position_pct', '.3f')} % of path (max {_cell(row, 'position_max_pct', '.3f')}), "
              f"rotation {_cell(row, 'rotation_deg', '.3f')} deg (max {_cell(row, 'rotation_max_deg', '.3f')}), "
              f"{row['seconds']:.1f} s", flush=True)
    by = {row["method"]: row for row in rows}
    if "camcal" in by and "position_pct" in by["camcal"]:
        for peer in ("pycolmap", "pycolmap-forward"):
            if peer in by and "position_pct" in by[peer]:
                print(f"  camcal / {peer}: position {by['camcal']['position_pct'] / by[peer]['position_pct']:.2f}, "
                      f"rotation {by['camcal']['rotation_deg'] / by[peer]['rotation_deg']:.2f}, "
                      f"time {by['camcal']['seconds'] / by[peer]['seconds']:.2f}")
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--data", type=Path, default=os.environ.get(ENV),
                        help=f"a KITTI-layout sequence or a folder of them (default: ${ENV})")
    parser.add_argument("--methods", default=",".join(METHODS), help=f"comma-separated, of {', '.join(METHODS)}")
    parser.add_argument("--json", type=Path, help="also write every row here")
    args = parser.parse_args()
    if args.data is None:  # make bench runs every bench without arguments: no data is a skip, not a failure
        print(f"bench_real_plate: skipped: set {ENV} (or give --data) to a KITTI-layout sequence or a folder of them")
        return
    methods = [m for m in args.methods.split(",") if m]
    rows = []
    with tempfile.TemporaryDirectory(prefix="bench_real_plate_") as tmp:
        for sequence in sequences(Path(args.data)):
            rows += compare(sequence, methods, Path(tmp) / sequence.name)
            shutil.rmtree(Path(tmp) / sequence.name, ignore_errors=True)
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()
