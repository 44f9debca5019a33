"""``camcal.solve``: cameras from image folders (pycolmap structure from motion + camcal's bundle adjustment)."""

from __future__ import annotations

import math
import os
import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from camcal.base.errors import CamcalError

if TYPE_CHECKING:
    from camcal.geometry.bundle import PriorSpec
    from camcal.model.quality import Quality
    from camcal.model.rig import Camera, Rig
    from camcal.pipelines.solve import PycolmapPeer, SfmResult

__all__ = ["UNCERTAINTY", "Solve", "solve"]

#: ``uncertainty`` -> the jackknife's replicate method (:data:`camcal.geometry.jackknife.METHODS`), None: covariance.
UNCERTAINTY = {"jackknife": "step", "jackknife-refit": "refit", "covariance": None}


@dataclass(frozen=True)
class Solve:
    """What :func:`solve` recovered and wrote.

    Attributes
    ----------
    sfm : SfmResult
        The reconstruction (:class:`camcal.pipelines.solve.SfmResult`): rig, registered images, RMS, bundle
        adjustment and self-calibration.
    out : Path
        The folder written: ``solve.rig.json``, ``points.ply``, the COLMAP model and ``colmap.log``.
    peer : PycolmapPeer or None
        With ``compare_pycolmap``: plain pycolmap's cameras on the same images.
    """

    sfm: SfmResult
    out: Path
    peer: PycolmapPeer | None = None

    @property
    def rig(self) -> Rig:
        """The solved rig (``out/solve.rig.json``)."""
        return self.sfm.rig

    @property
    def quality(self) -> dict[str, Quality]:
        """Each camera's fit quality by name (:class:`camcal.model.quality.Quality`: ``rms_px``, ``sigma``...)."""
        return {camera.name: camera.quality for camera in self.rig.cameras}

    @property
    def rms_px(self) -> float:
        """RMS reprojection error of every observation, in pixels."""
        return self.sfm.rms_px

    @property
    def files(self) -> tuple[tuple[Path, str], ...]:
        """``(path, kind)`` of what the solve wrote."""
        from camcal.pipelines.solve import COLMAP_LOG

        return ((self.out / "solve.rig.json", "rig"), (self.out / "points.ply", "points"),
                (self.sfm.reconstruction_dir, "colmap model"), (self.out / COLMAP_LOG, "log"))

    def save(self, path: str | os.PathLike) -> Path:
        """Write the rig to another file too (atomically); its path."""
        return self.rig.save(path)

    def lines(self) -> list[str]:
        """What ``solve`` prints: registered images, RMS, the refinement, each camera, the files."""
        from camcal.pipelines.solve import COLMAP_LOG

        result = self.sfm
        lines = [f"registered {result.n_registered} / {result.n_images} images", *result.notes]
        per_camera = ", ".join(f"{name} {rms:.3f} px" for name, rms in result.per_camera_rms_px.items())
        lines.append(f"RMS reprojection error: {result.rms_px:.3f} px ({per_camera}); {result.n_points} points")
        if result.bundle is not None:
            lines.append(result.bundle.summary())
        if result.self_calibration is not None:
            lines += result.self_calibration.lines()
        for camera in result.rig.cameras:
            sigma = camera.quality.get("sigma", {})
            lines.append(f"{camera.name}: {_intrinsics_line(camera, sigma)}"
                         + (f"; heldout RMS {camera.quality['heldout_rms_px']:.3f} px"
                            if "heldout_rms_px" in camera.quality else ""))
            if "rotation_deg" in sigma:
                lines.append(f"{camera.name}: rig pose sigma rotation {sigma['rotation_deg']:.3g} deg, "
                             f"baseline {100 * sigma['baseline_rel']:.3g} %")
            if self.peer is not None and camera.name in self.peer.cameras:
                lines.append(f"{camera.name} (plain pycolmap): {_intrinsics_line(self.peer.cameras[camera.name], {})}"
                             f"; RMS {self.peer.rms_px[camera.name]:.3f} px")
        lines.append(f"wrote {self.out / 'solve.rig.json'}, {self.out / 'points.ply'} and the COLMAP model in "
                     f"{result.reconstruction_dir} (COLMAP's log: {self.out / COLMAP_LOG})")
        return lines

    def figures(self) -> dict[str, Any]:
        """The figures of ``solve --json``."""
        result = self.sfm
        figures = dict(n_images=result.n_images, n_registered=result.n_registered,
                       unregistered=list(result.unregistered), notes=list(result.notes), rms_px=result.rms_px,
                       per_camera_rms_px=dict(result.per_camera_rms_px), n_points=result.n_points,
                       bundle=None if result.bundle is None else result.bundle.summary(),
                       cameras={camera.name: dict(camera.quality) for camera in result.rig.cameras})
        if result.self_calibration is not None:
            calibration = result.self_calibration

            def finite(value: float) -> float | None:
                return value if math.isfinite(value) else None

            figures.update(
                lens_models=calibration.lens_models, heldout_rms_px_by_model=calibration.heldout_rms_px,
                principal_point={d.camera: {"refined": d.refined, "determined": d.determined,
                                            "prior_sigma_px": finite(d.prior_sigma_px),
                                            "sigma_px": [finite(v) for v in d.sigma_px], "reason": d.reason}
                                 for d in calibration.principal_point},
                uncertainty={"covariance_sigmas": calibration.covariance_sigmas,
                             "jackknife_sigmas": calibration.jackknife_sigmas,
                             "jackknife_groups": calibration.jackknife_groups,
                             "jackknife_method": calibration.jackknife_method or None})
        if self.peer is not None:
            figures["pycolmap"] = {name: {"K": camera.K, "distortion": camera.distortion.to_dict(),
                                          "rms_px": self.peer.rms_px.get(name)}
                                   for name, camera in self.peer.cameras.items()}
        return figures


def _intrinsics_line(camera: Camera, sigma: Mapping[str, float]) -> str:
    """``f 900.12 +- 0.04 px, principal point (646.0, 474.3) +- (0.01, 0.02) px, division lambda -1.2e-07``."""
    def pm(key: str, fmt: str) -> str:
        return f" +- {sigma[key]:{fmt}}" if key in sigma else ""
    K = camera.K
    focal = f"f {K[0, 0]:.2f}{pm('fx', '.2g')}" if K[0, 0] == K[1, 1] else \
        f"fx {K[0, 0]:.2f}{pm('fx', '.2g')}, fy {K[1, 1]:.2f}{pm('fy', '.2g')}"
    lens = ", ".join(f"{name} {value:.4g}{pm(name, '.2g')}" for name, value in camera.distortion.params.items())
    return (f"{focal} px, principal point ({K[0, 2]:.2f}{pm('cx', '.2g')}, {K[1, 2]:.2f}{pm('cy', '.2g')}) px, "
            f"{camera.distortion.model} {lens}")


def _say_on_stderr(message: str) -> None:
    print(f"camcal solve: {message}", file=sys.stderr, flush=True)


def solve(
    folders: str | os.PathLike | Sequence[str | os.PathLike],
    out: str | os.PathLike,
    *,
    images: Mapping[str, str] | None = None,
    every: int = 1,
    frames: str | None = None,
    masks: Mapping[str, str] | None = None,
    rig: str | os.PathLike | Rig | None = None,
    model: str | None = None,
    camera_model: str | None = None,
    principal_point: str = "auto",
    priors: Sequence[str | PriorSpec] = (),
    uncertainty: str = "jackknife",
    features: int = 8192,
    guided_matching: bool = False,
    matcher: str = "exhaustive",
    loops: str = "auto",
    tracks: str = "auto",
    mapper: str = "incremental",
    loss: str = "trivial",
    refine: bool = True,
    compare_pycolmap: bool = False,
    intrinsics: str | os.PathLike | Rig | None = None,
    intrinsics_mode: str = "fixed",
    require_all: bool = False,
    up: str | None = None,
    origin: str | None = None,
    scale: str | None = None,
    units: str | None = None,
    world_board: str | None = None,
    readout_ms: float | str | None = None,
    readout_flag_px: float = 1.0,
    fps: float | None = None,
    seed: int = 0,
    scheduler: str | None = None,
    workers: int | None = None,
    verbose: bool = False,
    progress: bool | Callable[[str], None] = True,
) -> Solve:
    """Cameras from images (``camcal solve``): pycolmap structure from motion, then camcal's bundle adjustment.

    One folder per camera (or one folder of per-camera sub-folders, or
    ``images`` globs inside one folder); several cameras form a rig whose
    frames pair up by sorted order. Each camera's lens model is chosen by
    held-out residual; the principal point and the lens are refined under
    the sensor's Gaussian priors and ``priors``, and what the images do not
    determine is said with its sigma.

    Parameters
    ----------
    folders : path or sequence of paths
        Image folder(s).
    out : path
        The folder to write: ``solve.rig.json``, ``points.ply``, the COLMAP model, ``colmap.log``.
    images : mapping of str to str, optional
        Camera -> a glob (relative to the one folder, or absolute) or its video, e.g.
        ``{"left": "*_L.png", "right": "*_R.png"}``.
    every : int
        Videos: every N-th frame, streamed into ``out/images``.
    frames : str, optional
        Plates (a folder or an ``images`` entry with a frame placeholder,
        ``left.%04d.exr`` / ``left.####.dpx``): these frames, e.g.
        ``"1001-1100"`` (default: every frame on disk); a missing one is
        named before anything is written (:func:`camcal.io.sequence.sequence_paths`);
        given without a plate, an error.
    masks : mapping of str to str, optional
        Camera -> its matte sequence (same ``frames``), white where no
        feature may be taken (moving actors, the sky).
    rig : path or Rig, optional
        Hold the cameras' relative poses at this calibration (and take its units).
    model : str, optional
        camcal lens model (``auto``, ``division``, ``polynomial``, ``opencv``, ``none``, ``kannala-brandt``);
        default ``auto`` (chosen per camera by held-out residual), or the ``camera_model`` alone when given.
    camera_model : str, optional
        COLMAP camera model to map with.
    principal_point : {"auto", "refine", "centre"}
    priors : sequence of str or PriorSpec
        Gaussian priors on intrinsics, e.g. ``"left.f=1200+-30"``.
    uncertainty : {"jackknife", "jackknife-refit", "covariance"}
    features : int
        SIFT features per image (at least 100).
    guided_matching : bool
    matcher : {"exhaustive", "sequential"}
    loops : {"auto", "off"}
        With the sequential matcher, ``auto`` also matches the frames a retrieval finds revisiting an earlier
        part of the shot (VLAD over a vocabulary of the plate's own features, every second frame), verified by
        COLMAP; the pairs added and verified are a line of the result. The exhaustive matcher ignores it.
    tracks : {"auto", "refine", "detected"}
        ``refine``: before camcal's bundle adjustment, every observation of a track is moved to where its
        neighbourhood best matches the track's middle observation under an affine warp
        (:mod:`camcal.geometry.track_refine`); the detected SIFT positions move with the viewpoint, which on a
        pan the focal length absorbs (a rendered 240-frame dolly with a 30 deg pan: focal error +0.26 % from the
        detected positions, +0.07 % refined). ``detected``: the keypoints as detected. ``auto``: ``refine`` with
        the sequential matcher, ``detected`` otherwise.
    mapper : {"incremental", "global"}
    loss : str
        Robust loss of camcal's bundle adjustment (scale 1 px).
    refine : bool
        False keeps pycolmap's result.
    compare_pycolmap : bool
        Also run plain pycolmap on the same images into ``out/pycolmap``.
    intrinsics : path or Rig, optional
        A grid calibration (``calibrate board``): each camera takes its lens (by name; one camera each: the
        one), at the plate's size (the same aspect at another size scales ``K``, said; another aspect is an
        error naming both sizes); the lens-model choice is skipped.
    intrinsics_mode : {"fixed", "prior"}
        Hold that lens, or refine it under a Gaussian prior of the grid's sigmas (the move is said in sigmas).
    require_all : bool
        An image that cannot be registered is an error (nothing written) instead of a line naming its frame.
    up : {"ground", "cameras"}, optional
        After the solve, turn the world so that +z is up: the normal of the ground plane (RANSAC on the
        sparse points) or the cameras' mean up; the first camera then looks down +y.
    origin : str, optional
        The point that becomes the origin: ``"ground"`` (the ground under the first camera), a point's row in
        ``points.ply`` (``"12"``) or coordinates in the solve's world (``"0.5:-1.2:3"``).
    scale : str, optional
        ``"A,B=DIST"``: two points (rows or coordinates) and their known distance, e.g. ``"12,40=1.5"``.
    units : str, optional
        The unit of that distance or of ``world_board``'s squares, recorded in the rig (default ``"m"`` with
        ``scale`` or ``world_board``).
    world_board : str, optional
        A board lying in the set, e.g. ``"chessboard:9x6:0.04"`` (the ``calibrate board`` spec): found in up to
        24 registered images, its corners triangulated from the solved cameras, it sets the world: its plane the
        ground (+z towards the cameras), its first inner corner the origin, +x along its columns, its squares
        the scale. Not with ``up``, ``origin`` or ``scale``.
    readout_ms : float, "typical" or "estimate", optional
        The camera's rolling-shutter readout time (top row to bottom row, ms; ``"typical"``: 30 ms, a consumer
        camera's): each solved frame's points are moved by the camera's motion during the readout (velocities
        from the neighbouring frames, :mod:`camcal.geometry.rolling_shutter`); the largest displacement is
        stored per frame and camera in the rig (``frames[i].rolling_shutter``) and the frames above
        ``readout_flag_px`` are named in a line. ``"estimate"``: the readout is estimated per camera by a
        rolling-shutter bundle adjustment of the solved plate (:mod:`camcal.geometry.rolling_shutter_ba`), stored
        with its standard deviation in ``rig.provenance["rolling_shutter"]["estimate"]`` and used for the check;
        where the plate's motion does not determine it (moving straight or sideways at a constant speed), a line
        says so and that camera's frames are not checked. Default: no check (a global shutter assumed).
    readout_flag_px : float
        The displacement (px) above which a frame is flagged.
    fps : float, optional
        The plate's frame rate, which times the frames for the velocities (default: a movie's own, else 24).
    seed : int
        Seeds every random choice: the same images and options give the same rig.
    scheduler : str, optional
        Extract the features on the Dask cluster of this scheduler (``"tcp://farm:8786"``), one task per image,
        then match them there, one task per block of image pairs (matched and verified), whose workers must see
        the images and the folder ``out`` is in: the same features, matches and rig as in this process, each
        image's features and each block's matches kept in ``out/.camcal-features`` until the solve ends, so that
        a rerun of a killed solve does only what it had not finished. The mapping stays in this process.
    workers : int, optional
        The same on a local Dask cluster of this many worker processes (not with ``scheduler``).
    verbose : bool
        Also show COLMAP's own log lines on stderr.
    progress : bool or callable
        True: the stages on stderr as ``camcal solve: ...``; a callable receives each stage's message.

    Returns
    -------
    Solve

    Raises
    ------
    CamcalError
        Bad input (one line naming it); a failed solve leaves nothing behind in ``out``.
    """
    from camcal.base.globs import expand_glob
    from camcal.io.sequence import is_sequence_pattern, sequence_paths
    from camcal.geometry.bundle import parse_prior
    from camcal.geometry.selfcal import LENS_MODELS, MAPPING_MODELS
    from camcal.model.rig import Rig
    from camcal.pipelines.solve import collect_images, solve_pycolmap_plain, solve_sfm
    from camcal.pipelines.solve_lens import LENS_MODES
    from camcal.pipelines.solve_shutter import shutter_spec
    from camcal.pipelines.solve_world import world_spec

    folders = [Path(folders)] if isinstance(folders, (str, os.PathLike)) else [Path(folder) for folder in folders]
    shutter = shutter_spec(readout_ms, readout_flag_px, fps)
    if uncertainty not in UNCERTAINTY:
        raise CamcalError(f"unknown uncertainty {uncertainty!r}, expected one of: {', '.join(UNCERTAINTY)}")
    if frames is not None and not any(map(is_sequence_pattern, [*folders, *(images or {}).values()])):
        raise CamcalError(f"frames {frames!r} given, but no folder or images entry is a plate with a frame "
                          "placeholder (left.%04d.exr, left.####.dpx)")
    if images:
        if len(folders) != 1:
            raise CamcalError("--images NAME=GLOB selects images inside one folder: give exactly one, "
                              f"got {len(folders)}")
        if not folders[0].is_dir():
            raise CamcalError(f"image folder not found: {folders[0]}")
        found = {name: sequence_paths(folders[0] / pattern, frames) if is_sequence_pattern(pattern)
                 else [Path(f) for f in expand_glob("--images", name, pattern, root=folders[0])]
                 for name, pattern in images.items()}
    else:
        found = collect_images(folders, frames=frames)
    mattes = {name: sequence_paths(pattern, frames) for name, pattern in (masks or {}).items()}
    known_rig = rig if isinstance(rig, Rig) or rig is None else Rig.load(rig)
    if intrinsics_mode not in LENS_MODES:
        raise CamcalError(f"unknown intrinsics mode {intrinsics_mode!r}, expected one of: {', '.join(LENS_MODES)}")
    grid = intrinsics if isinstance(intrinsics, Rig) or intrinsics is None else Rig.load(intrinsics)
    if grid is not None and (model is not None or camera_model is not None):
        raise CamcalError("--intrinsics gives the lens: --model and --camera-model choose one, give one or the other")
    world = world_spec(up, origin, scale, units, world_board)
    if features < 100:
        raise CamcalError(f"--features must be at least 100, got {features}")
    # auto (or nothing): choose among LENS_MODELS; a named model: only it; camera_model alone: keep it
    model = model or ("keep" if camera_model else "auto")
    lens_models = LENS_MODELS if model == "auto" else (None if model == "keep" else (model,))
    # COLMAP marks fisheye pairs without a focal prior as degenerate (no match survives): a fisheye maps with
    # SIMPLE_RADIAL and becomes kannala-brandt in the self-calibration (a fit of the lens, then the bundle)
    mapped = model in MAPPING_MODELS and model != "kannala-brandt"
    camera_model = camera_model or (MAPPING_MODELS[model] if mapped else "SIMPLE_RADIAL")
    say = _say_on_stderr if progress is True else (progress or None)
    out = Path(out)
    result = solve_sfm(found, out, camera_model=camera_model, matcher=matcher, loops=loops, tracks=tracks,
                       mapper=mapper,
                       seed=seed, refine=refine, known_rig=known_rig, loss=loss, lens_models=lens_models,
                       principal_point=principal_point, max_num_features=features, jackknife=UNCERTAINTY[uncertainty],
                       priors=tuple(parse_prior(p) if isinstance(p, str) else p for p in priors), verbose=verbose,
                       guided_matching=guided_matching, every=every, masks=mattes, progress=say, intrinsics=grid,
                       intrinsics_mode=intrinsics_mode,
                       intrinsics_source=str(intrinsics) if grid is not None and not isinstance(intrinsics, Rig)
                       else "the grid", world=world, require_all=require_all, rolling_shutter=shutter,
                       scheduler=scheduler, workers=workers)
    peer = (solve_pycolmap_plain(found, out / "pycolmap", seed=seed, verbose=verbose, every=every)
            if compare_pycolmap else None)
    return Solve(result, out, peer)
