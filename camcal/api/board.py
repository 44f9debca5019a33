"""``camcal.calibrate_board``: one camera or an N-camera rig from board images or videos, as ``calibrate board``.

The function is what the command runs: the globs, videos (in threads or on
Dask), timestamps, held-out views, view selection, the quality gate, the
report and the suggested next views are here; the command parses its
options, calls :func:`calibrate_board` and prints the result.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from camcal.base.errors import CamcalError

if TYPE_CHECKING:
    from camcal.geometry.board import Board, Detection, DetectionReport
    from camcal.geometry.suggest import SuggestedView
    from camcal.geometry.zhang import CalibrationResult
    from camcal.io.timestamps import Synchronisation, Timestamps
    from camcal.model.quality import Quality
    from camcal.model.rig import Rig

__all__ = ["BoardCalibration", "CameraInputs", "calibrate_board"]

#: A camera's images: a glob or a video (``"shots/left*.jpg"``, ``"cam0.mp4"``) or the image files themselves.
CameraInputs = str | os.PathLike | Sequence[str | os.PathLike]


@dataclass(frozen=True)
class BoardCalibration:
    """What :func:`calibrate_board` found and wrote.

    Attributes
    ----------
    calibration : CalibrationResult
        The fit (:class:`camcal.geometry.zhang.CalibrationResult`): the rig, residuals, rankings, held-out RMS.
    board : Board
    detections : mapping of str to DetectionReport
        Camera -> the board found in its images or video frames (and where it was not).
    views : mapping of str to tuple of Detection
        Camera -> the views calibrated on (with ``timestamps``: renumbered by time, unmatched ones dropped).
    quality_problems : tuple of str
        Why the quality gate refuses the calibration (:func:`camcal.geometry.zhang.quality_problems`); not empty
        only when ``force=True`` wrote it anyway.
    synchronisation : Synchronisation or None
        With ``timestamps``: each camera's frames matched to the first camera's.
    dropped_by_time : mapping of str to int
        With ``timestamps``: camera -> its views without a match in time.
    suggested : tuple of SuggestedView
        With ``suggest=N``: the next board poses that most lower the first camera's worst projection sigma.
    files : tuple of (Path, str)
        ``(path, kind)`` of every file written (kinds ``rig``, ``suggest``, ``report``), in that order.
    """

    calibration: CalibrationResult
    board: Board
    detections: Mapping[str, DetectionReport]
    views: Mapping[str, tuple[Detection, ...]]
    quality_problems: tuple[str, ...] = ()
    synchronisation: Synchronisation | None = None
    dropped_by_time: Mapping[str, int] = field(default_factory=dict)
    suggested: tuple[SuggestedView, ...] = ()
    files: tuple[tuple[Path, str], ...] = ()

    @property
    def rig(self) -> Rig:
        """The calibrated cameras (the first is the reference: ``R = I``, ``c = 0``)."""
        return self.calibration.rig

    @property
    def quality(self) -> dict[str, Quality]:
        """Each camera's fit quality by name (:class:`camcal.model.quality.Quality`: ``rms_px``, ``sigma``...)."""
        return {camera.name: camera.quality for camera in self.rig.cameras}

    @property
    def rms_px(self) -> float:
        """RMS reprojection error over every corner kept, in pixels."""
        return self.calibration.rms_px

    @property
    def worst_px(self) -> float:
        """Largest reprojection error (per-corner norm), in pixels."""
        return self.calibration.worst_px

    @property
    def heldout_rms_px(self) -> float | None:
        """RMS over the held-out views (posed with the intrinsics held), in pixels; None without any."""
        return self.calibration.heldout_rms_px

    @property
    def passed(self) -> bool:
        """True when the quality gate found nothing wrong."""
        return not self.quality_problems

    def save(self, path: str | os.PathLike) -> Path:
        """Write the rig file (atomically) and return its path."""
        return self.rig.save(path)

    def lines(self) -> list[str]:
        """The summary ``calibrate board`` prints after its run: rankings, RMS, each camera, the next views."""
        from camcal.geometry.zhang_result import ranking_lines

        result = self.calibration
        lines = list(result.notes)
        estimated = any(s.estimated for s in (*result.model_ranking, *result.shape_ranking))
        how = ("each one's leave-one-view-out error estimated from its one fit" if estimated
               else "views held out in turn")
        if result.model_ranking:
            lines.append(f"model auto: {how}, chose {result.model}")
            lines += ["  " + line for line in ranking_lines(result.model_ranking)]
        if result.shape_ranking:
            lines.append(f"board shape auto: {how}" + ("" if estimated else " (the same folds; the lenses ranked "
                                                       "again on the surface taken)"))
            lines += ["  " + line for line in ranking_lines(result.shape_ranking)]
        if result.dropped:
            lines.append("dropped (no corner labelling agrees with the rig): "
                         + ", ".join(image for _, image in result.dropped))
        lines.append(result.summary())
        if result.outliers:
            lines.append("dropped as outliers: " + ", ".join(image for _, image in result.outliers))
        lines += [_camera_line(camera, self.rig.units) for camera in self.rig.cameras]
        if self.suggested:
            camera = self.rig.cameras[0]
            preview = next((path for path, kind in self.files if kind == "suggest"), None)
            where = "" if preview is None else f" (preview {preview})"
            lines.append(f"{camera.name}: worst projection sigma now {camera.quality['worst_projection_sigma_px']:.3g}"
                         f" px; next views{where}:")
            lines += [f"  {number}. {shot.describe()}" for number, shot in enumerate(self.suggested, start=1)]
        return lines

    def figures(self) -> dict[str, Any]:
        """The figures of ``calibrate board --json`` (numbers named with their units)."""
        result = self.calibration

        def ranking(scores) -> list[dict]:
            return [{"model": s.model, "rms_px": s.rms_px, "n_params": s.n_params, "reason": s.reason} for s in scores]

        figures = dict(
            summary=result.summary(), outliers=[image for _, image in result.outliers],
            detections={name: len(found) for name, found in self.views.items()},
            cameras={camera.name: {"K": camera.K, "distortion": camera.distortion.to_dict(), "c": camera.c,
                                   "quality": camera.quality.to_dict()} for camera in self.rig.cameras},
            model=result.model, heldout_rms_px=result.heldout_rms_px,
            model_heldout_rms_px=dict(result.model_heldout_rms_px), model_ranking=ranking(result.model_ranking),
            relabelled=[image for _, image in result.relabelled], dropped=[image for _, image in result.dropped],
            board_shape=None if result.board_shape is None else result.board_shape.to_dict(),
            shape_ranking=ranking(result.shape_ranking), quality_problems=list(self.quality_problems),
        )
        if self.synchronisation is not None:
            sync = self.synchronisation
            figures["synchronisation"] = {"reference": sync.reference, "tolerance_s": sync.tolerance_s,
                                          "offsets_s": dict(sync.offsets_s), "dropped": dict(self.dropped_by_time)}
        if self.suggested:
            figures["suggested"] = [{"centre_px": shot.centre_px, "distance": shot.distance,
                                     "tilt_deg": list(shot.tilt_deg), "R": shot.R, "t": shot.t,
                                     "worst_sigma_px": shot.worst_sigma_px} for shot in self.suggested]
        return figures


def _camera_line(camera, units: str) -> str:
    """``left: fx 1.00 +/- 0.01  fy ...  principal point (...) +/- (...) px  RMS 0.123 px`` (and the baseline)."""
    import numpy as np

    K, sigma = camera.K, camera.quality["sigma"]
    line = (f"{camera.name}: fx {K[0, 0]:.2f} +/- {sigma['fx']:.2f}  fy {K[1, 1]:.2f} +/- {sigma['fy']:.2f}  "
            f"principal point ({K[0, 2]:.2f}, {K[1, 2]:.2f}) +/- ({sigma['cx']:.2f}, {sigma['cy']:.2f}) px  "
            f"RMS {camera.quality['rms_px']:.3f} px")
    if camera.quality.get("heldout_rms_px") is not None:
        line += f" (held-out {camera.quality['heldout_rms_px']:.3f} px)"
    if "baseline_rel" in sigma:
        baseline = float(np.linalg.norm(camera.c))
        line += (f"  baseline {baseline:.4f} +/- {sigma['baseline_rel'] * baseline:.4f} {units}"
                 f"  rotation +/- {sigma['rotation_deg']:.3f} deg")
    return line


def calibrate_board(
    images: Mapping[str, CameraInputs] | CameraInputs,
    board: str | Board,
    *,
    model: str = "auto",
    board_shape: str = "auto",
    thorough: bool = False,
    units: str = "m",
    every: int = 1,
    timestamps: str | os.PathLike | Timestamps | None = None,
    time_tolerance_s: float | None = None,
    intrinsics: str | os.PathLike | Rig | None = None,
    refine_intrinsics: bool = False,
    holdout: str | float | Iterable[int] | None = None,
    max_views: int | None = None,
    loss: str = "trivial",
    loss_scale: float = 1.0,
    workers: int | None = None,
    scheduler: str | None = None,
    cache: str | os.PathLike | bool = True,
    force: bool = False,
    suggest: int = 0,
    out: str | os.PathLike | None = None,
    report: str | os.PathLike | None = None,
    suggest_preview: str | os.PathLike | None = None,
    progress: bool = True,
    log: Callable[[str], None] | None = None,
) -> BoardCalibration:
    """Calibrate one camera or a rig from board images or videos (``camcal calibrate board``).

    Detects the board in every image (worker threads, cached by content) or
    video frame (streamed; 2000 frames or more on a local Dask cluster, or on
    ``scheduler``), calibrates each camera with OpenCV, then refines every
    intrinsic, lens and pose jointly (:func:`camcal.geometry.zhang.calibrate_board`).
    Views of several cameras are matched by the frame number in their file
    names (of a video: frame k is its k-th frame), or by time
    (``timestamps``); the first camera is the reference (``R = I``, ``c = 0``).

    Parameters
    ----------
    images : mapping of str to (glob, video or image files), or one of them
        Camera name -> its images: a glob (absolute, or relative to the working folder), a video
        (``.mp4 .mov .avi .mkv``) or a list of files, e.g. ``{"left": "shots/left*.jpg", "right":
        "shots/right*.jpg"}``. One camera's images alone are named ``camera``.
    board : str or Board
        ``"chessboard:WxH:SQUARE[:two-sided]"`` (inner corners) or
        ``"charuco:DICT:WxH:SQUARE:MARKER[:inverted][:two-sided][:legacy]"`` (squares), or a
        :class:`camcal.geometry.board.Board`.
    model : str
        Lens model (:data:`camcal.geometry.zhang.MODELS`, ``MODEL+spline``) or ``"auto"`` (ranked by views held
        out, each candidate's leave-one-view-out error estimated from its one fit; the simplest within 1 % of the
        best).
    board_shape : str
        ``"auto"``, ``"flat"``, or a surface (``"2"``, ``"4+plane"``, ``"free"``...), one camera.
    thorough : bool
        With ``"auto"``: rank by views held out in turn, fold by fold (the correction field and the lenses on the
        board surface taken ranked too): dozens of fits instead of about one per candidate.
    units : str
        Unit of the board's square size, stored in the rig.
    every : int
        Videos: detect every N-th frame.
    timestamps : path or Timestamps, optional
        Frame times (CSV ``camera,frame,time``): views matched to the first camera's nearest in time.
    time_tolerance_s : float, optional
        With ``timestamps``: the largest time difference of a match (default: half the first camera's period).
    intrinsics : path or Rig, optional
        Every camera's K and lens, held (only the poses are solved) unless ``refine_intrinsics``.
    refine_intrinsics : bool
        With ``intrinsics``: start from them and refine them.
    holdout : str, float or iterable of int, optional
        Frames left out of the fit and reported as held-out RMS: ``"21-25,3"``, a fraction (``0.2``) or frame
        numbers.
    max_views : int, optional
        Solve on at most this many frames, chosen for coverage; the others are held out.
    loss, loss_scale : str, float
        Robust loss on each corner (``trivial``, ``huber``, ``soft_l1``, ``cauchy``) and its scale in pixels.
    workers : int, optional
        Images or frames detected at once (default: the CPU count).
    scheduler : str, optional
        ``tcp://HOST:PORT`` of a Dask cluster that detects video frames.
    cache : path or bool
        Corner cache directory; True: ``$XDG_CACHE_HOME/camcal/corners``; False: detect again.
    force : bool
        Return (and write) a calibration that fails the quality gate instead of raising.
    suggest : int
        Propose the next N board poses that most lower the first camera's worst projection sigma.
    out : path, optional
        The ``*.rig.json`` to write (atomically, with ``report``).
    report : path, optional
        A folder for PNG plots: residuals, per-image RMS, coverage, projection sigma heat maps.
    suggest_preview : path, optional
        With ``suggest`` and ``out``: the PNG of the shot list (default: ``out`` without ``.rig.json`` +
        ``.suggest.png``).
    progress : bool
        Draw progress bars on stderr.
    log : callable, optional
        Receives each line the command prints while it runs (the boards found, the synchronisation...), e.g.
        ``print``; :meth:`BoardCalibration.lines` holds the summary after it.

    Returns
    -------
    BoardCalibration

    Raises
    ------
    CamcalError
        Bad input (one line naming it), or a calibration that fails the quality gate (principal point outside
        the image, RMS over 1.5 px, sigma fx over 5 %) without ``force``; nothing is written then.

    Examples
    --------
    >>> import camcal  # doctest: +SKIP
    >>> result = camcal.calibrate_board({"left": "shots/left*.jpg", "right": "shots/right*.jpg"},
    ...                                 "chessboard:9x6:0.03", out="stereo.rig.json")  # doctest: +SKIP
    >>> print(result.rms_px, result.rig.cameras[1].c)  # doctest: +SKIP
    """
    from camcal.geometry.board import Board, frame_number, parse_board
    from camcal.geometry.zhang import calibrate_board as fit_board, quality_problems
    from camcal.model.rig import Rig

    say = log or (lambda line: None)
    board = board if isinstance(board, Board) else parse_board(board)
    if isinstance(images, (str, os.PathLike)) or (isinstance(images, Sequence) and not isinstance(images, Mapping)):
        images = {"camera": images}
    cameras = dict(images)
    if not cameras:
        raise CamcalError("--images: give at least one camera, e.g. --images left='shots/left*.jpg'")
    if every < 1:
        raise CamcalError(f"--every must be 1 or more, got {every}")
    if max_views is not None and max_views < 1:
        raise CamcalError(f"--max-views must be 1 or more, got {max_views}")
    if refine_intrinsics and intrinsics is None:
        raise CamcalError("--refine-intrinsics needs --intrinsics RIG (the start)")
    if time_tolerance_s is not None and timestamps is None:
        raise CamcalError("--time-tolerance needs --timestamps FILE.csv")
    if time_tolerance_s is not None and not (0 < time_tolerance_s < float("inf")):
        raise CamcalError(f"--time-tolerance must be a positive number of seconds, got {time_tolerance_s}")
    if timestamps is not None and isinstance(timestamps, (str, os.PathLike)):
        from camcal.io.timestamps import read_timestamps

        timestamps = read_timestamps(timestamps)
    if timestamps is not None:
        timestamps.check_cameras(list(cameras))
    held_intrinsics, shape = None, board_shape
    if intrinsics is not None:
        given = intrinsics if isinstance(intrinsics, Rig) else Rig.load(intrinsics)
        where = "the given rig" if isinstance(intrinsics, Rig) else str(intrinsics)
        held_intrinsics = {camera.name: camera for camera in given.cameras}
        if ("board_shape" in given.provenance and board_shape == "auto"
                and given.provenance.get("board") == board.spec()):
            from camcal.geometry.board_shape import BoardShape

            shape = BoardShape.from_dict(given.provenance["board_shape"])
            say(f"--intrinsics {where}: its board's surface is held ({shape.describe(board)})")
        missing = [name for name in cameras if name not in held_intrinsics]
        if missing:
            raise CamcalError(f"--intrinsics {where}: no camera named {', '.join(missing)} "
                              f"(it has: {', '.join(held_intrinsics)})")
    reports, videos = _detect(board, cameras, every, timestamps is not None, workers, scheduler, cache, progress, say)
    detections = {name: report.detections for name, report in reports.items()}
    synchronisation, dropped = None, {}
    if timestamps is not None:
        from camcal.pipelines.board import synchronise_detections

        detections, synchronisation, dropped = synchronise_detections(
            reports, timestamps, time_tolerance_s, sources={name: str(path) for name, path in videos.items()},
            every=every)
        say(f"synchronised by time ({timestamps.path}): views numbered by {synchronisation.reference}'s frames, "
            f"matched within {1e3 * synchronisation.tolerance_s:.3g} ms")
        for name in cameras:
            offset = ("" if name == synchronisation.reference
                      else f", {synchronisation.offsets_s[name]:+.4f} s from {synchronisation.reference}")
            say(f"  {name}: {len(detections[name])} views kept, {dropped[name]} dropped (no frame of "
                f"{synchronisation.reference} within the tolerance, or no time){offset}")
    held = _held_out(holdout, sorted({frame_number(d.image) for views in detections.values() for d in views}))
    if max_views is not None:
        from camcal.geometry.view_selection import select_frames

        frames = {frame_number(d.image) for views in detections.values() for d in views} - held
        chosen = select_frames(board, detections, max_views, intrinsics=held_intrinsics, exclude=held)
        if len(chosen) < len(frames):
            say(f"solving on {len(chosen)} of {len(frames)} frames, chosen for coverage (--max-views); the other "
                f"{len(frames) - len(chosen)} are held out")
            held |= frames - set(chosen)
    result = fit_board(board, detections, model=model, units=units, loss=loss, loss_scale=loss_scale, holdout=held,
                       intrinsics=held_intrinsics, refine_intrinsics=refine_intrinsics, board_shape=shape,
                       thorough=thorough)
    problems = tuple(quality_problems(result))
    if problems and not force:
        raise CamcalError("calibration refused, its own figures show it broken: " + "; ".join(problems)
                          + " (--force writes it anyway)")
    shots = ()
    if suggest > 0:
        from camcal.geometry.suggest import pose_views, suggest_views

        camera = result.rig.cameras[0]
        kept = {image for name, image in result.images if name == camera.name}
        views = [d for d in detections[camera.name] if d.image in kept]
        shots = tuple(suggest_views(camera, board.object_points, pose_views(camera, board.object_points, views),
                                    suggest))
    files = _write(result, board, shots, out, report, suggest_preview)
    return BoardCalibration(result, board, reports, {name: tuple(views) for name, views in detections.items()},
                            problems, synchronisation, dropped, shots, files)


def _held_out(holdout: str | float | Iterable[int] | None, frames: list[int]) -> set[int]:
    """The frames ``holdout`` names: ranges or a fraction as text (:func:`camcal.base.frame_ranges.parse_holdout`),
    a fraction as a number, or frame numbers."""
    from camcal.base.frame_ranges import parse_holdout

    if holdout is None or holdout == "":
        return set()
    if isinstance(holdout, str):
        return parse_holdout(holdout, frames)
    if isinstance(holdout, float):
        if not 0 < holdout < 1:
            raise CamcalError(f"bad holdout {holdout!r}: a fraction is between 0 and 1")
        return parse_holdout(repr(holdout), frames)
    return {int(frame) for frame in holdout}


def _detect(board: Board, cameras: dict, every: int, by_time: bool, workers: int | None, scheduler: str | None,
            cache: str | os.PathLike | bool, progress: bool, say: Callable[[str], None]) -> tuple[dict, dict]:
    """Every camera's :class:`DetectionReport` (in the order of ``cameras``) and its videos (name -> path)."""
    from camcal.base.globs import expand_glob
    from camcal.base.progress import Progress
    from camcal.geometry.board import frame_number
    from camcal.io.video import is_video, video_info
    from camcal.pipelines.board import default_cache_dir, detect_in_images, detect_in_video
    from camcal.pipelines.distributed import detect_in_videos, use_dask

    videos = {name: value for name, value in cameras.items()
              if isinstance(value, (str, os.PathLike)) and is_video(os.fspath(value))}
    # every video decodable before any work; the containers' frame counts (estimates) size the progress
    frame_counts = {name: video_info(video).frame_count for name, video in videos.items()}
    files = {name: expand_glob("--images", name, os.fspath(value)) if isinstance(value, (str, os.PathLike))
             else [os.fspath(path) for path in value] for name, value in cameras.items() if name not in videos}
    for name, listed in files.items():
        if not listed:
            raise CamcalError(f"--images {name}: no image given")
    n_workers = workers or os.cpu_count() or 1
    folder = None if cache is False else (default_cache_dir() if cache is True else cache)
    first = next(iter(cameras))
    # by time, another camera's frames matching the first camera's 0, N, 2N... are not its own 0, N, 2N...
    steps = {name: 1 if by_time and name != first else every for name in videos}

    def bar(total: int, label: str, unit: str):
        return Progress(total, label, unit).report if progress else None

    on_dask: dict = {}
    n_video_frames = sum(-(-frame_counts[name] // steps[name]) for name in videos)
    if videos and use_dask(n_video_frames, scheduler):
        for step in sorted(set(steps.values())):
            group = {name: path for name, path in videos.items() if steps[name] == step}
            on_dask |= detect_in_videos(board, group, every=step, workers=workers, scheduler=scheduler, cache=folder,
                                        progress=bar(n_video_frames, f"detecting {len(group)} camera(s) on Dask",
                                                     "frames"))
    reports = {}
    for name in cameras:
        if name in videos:
            total = max(1, -(-frame_counts[name] // steps[name]))
            report = on_dask[name] if name in on_dask else detect_in_video(
                board, videos[name], every=steps[name], workers=n_workers, cache=folder,
                progress=bar(total, f"detecting {name}", "frames"))
            skipped = [str(frame_number(label)) for label in report.skipped]
            text = f"{name}: board found in {len(report.detections)} / {report.n_images} frames of {videos[name]}"
            if skipped:
                text += f" (not in frames {', '.join(skipped[:12])}{', ...' if len(skipped) > 12 else ''})"
            say(text)
        else:
            report = detect_in_images(board, files[name], progress=bar(len(files[name]), f"detecting {name}",
                                                                        "images"), workers=n_workers, cache=folder)
            say(f"{name}: {report.summary()}")
        reports[name] = report
    return reports, videos


def _write(result: CalibrationResult, board: Board, shots: tuple, out: str | os.PathLike | None,
           report: str | os.PathLike | None, suggest_preview: str | os.PathLike | None) -> tuple[tuple[Path, str], ...]:
    """Write the rig and the report folder (atomically, together), then the shot list's preview."""
    from camcal.base.atomic import final_path, output_folder

    with output_folder(report) as report_dir:
        written = []
        if report_dir is not None:
            from camcal.report.calibration import write_report
            from camcal.report.sigma import write_sigma_heatmaps

            sigma_maps = write_sigma_heatmaps(result.rig.cameras, report_dir)
            written = write_report(result, report_dir, board, sigma_maps) + sigma_maps
        files = [] if out is None else [(result.rig.save(out), "rig")]
    if shots and out is not None:
        from camcal.report.calibration import write_suggestion_preview

        out_path = os.fspath(out)
        preview = suggest_preview or (out_path[:-len(".rig.json")] if out_path.endswith(".rig.json")
                                      else out_path) + ".suggest.png"
        files.append((write_suggestion_preview(result.rig.cameras[0], shots, preview), "suggest"))
    return tuple(files) + tuple((final_path(path, report_dir, report), "report") for path in written)
