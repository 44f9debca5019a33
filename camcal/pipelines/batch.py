"""Plates at scale: undistort, rectify and colour-correct image sequences, locally or on a Dask cluster.

A job (:class:`BatchJob`) is everything one frame needs: the camera (K,
distortion, rectification), the geometric step (``undistort``,
``rectify`` or none), the colour fit (or none) and the input and output
filename patterns (``plates/left.%04d.exr``). :func:`run_batch` sends one
Dask task per frame (:func:`process_frame`) to a ``distributed``
scheduler: an embedded ``LocalCluster`` by default, or the user's cluster
given by address. Dask does the scheduling, the retries (``retries=``)
and the recovery from lost workers; nothing here schedules.

Per worker, not per frame
-------------------------
The remap maps (:func:`camcal.geometry.remap.build_maps`, the same ones
``camcal undistort`` and ``camcal rectify`` use) and the colour step are
built once per worker process, on its first frame of a job, and cached by
the job's key (:attr:`BatchJob.key`, a SHA-256 of everything that changes
the pixels). The job travels in the task graph, held by the scheduler (a
few kilobytes per frame), not scattered to the workers: data scattered to
a worker is lost with it, and a broadcast fails when a worker dies during it.

Pixels
------
Frames keep their depth, channels and (EXR) metadata
(:mod:`camcal.io.frames`). Without colour, the geometric step remaps the
frame in its own type (exactly what ``camcal undistort`` writes). With
colour, code values ``V / V_max`` (``V_max`` 255, 65535, or 1 for float)
are turned into the job's output space (:class:`ColourStep`: the OCIO CPU
processor of the fit's exported transform, :meth:`ColourFit.processor`:
linearisation, model, then ACES2065-1, ACEScg, linear Rec. 709 or the
fit's CIE XYZ; that space's R, G, B (or X, Y, Z) in the R, G, B channels,
other channels untouched), the frame is remapped in float32 (interpolating
linear values) and, for an integer format, quantised back as
``round(clip(value, 0, 1) V_max)``.

Output and resume
-----------------
Every frame is written atomically (temporary file + rename); after it, a
record ``<out dir>/.camcal-batch/<file name>.json`` gives the job key, the
frame, the file's size and modification time, the run and the worker.
With ``resume=True`` a frame is skipped when its output exists and its
record names this job with the file's present size and modification time
(so a file rewritten or replaced since is redone). A write interrupted by
a killed worker or client leaves no partial output, only its temporary
file (``.NAME.camcal-tmp.XXXXXXXX.SUFFIX``, :mod:`camcal.base.atomic`);
every run removes those of the frames it is about to write (and of their
records) when it starts, and again when it ends or fails, once its cluster
is closed (a worker killed during the run leaves its own). Only camcal's
temporary names for this run's outputs are touched; one run at a time
writes a given output folder.
A frame that still fails after its retries is reported by number in the
:class:`BatchReport`; the others are written.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import os
import re
import socket
import threading
import time
import uuid
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from camcal.base.atomic import remove_stale_temporaries
from camcal.base.errors import CamcalError
from camcal.base.jsonfile import read_json, write_json
from camcal.base.progress import Progress
from camcal.colour.export.ocio_fit import fit_processor
from camcal.colour.fit.record import ColourFit
from camcal.geometry.remap import RemapMaps, build_maps
from camcal.geometry.undistort import MODES, make_undistorter
from camcal.io.colourfile import load_fit
from camcal.io.frames import ImageFrame, frame_format, read_frame, write_frame
from camcal.io.sequence import printf_pattern, sequence_paths
from camcal.model.rig import Camera, Rig
from camcal.pipelines.distributed import dask_client

__all__ = [
    "GEOMETRY",
    "COLOUR_SPACES",
    "RECORD_DIR",
    "BatchJob",
    "ColourStep",
    "FrameProcessor",
    "FrameResult",
    "FrameFailure",
    "BatchReport",
    "frame_path",
    "make_job",
    "process_frame",
    "record_path",
    "completed_frames",
    "run_batch",
]

#: Geometric steps a job can do (or None: colour only).
GEOMETRY = ("undistort", "rectify")
#: Output spaces of the colour step (camcal.colour.export.ocio_fit.OUTPUT_SPACES).
COLOUR_SPACES = ("ACES2065-1", "ACEScg", "lin Rec.709", "CIE XYZ")
#: Folder, beside the outputs, of the per-frame completion records.
RECORD_DIR = ".camcal-batch"
_RECORD_FORMAT = "camcal.batch-frame"
_PATTERN = re.compile(r"%(0\d+)?d")
_CACHE_SIZE = 4


# -- frames and patterns ------------------------------------------------------------


def _check_pattern(pattern: str, what: str) -> str:
    placeholders = _PATTERN.findall(pattern)
    if len(placeholders) != 1 or pattern.replace("%%", "").count("%") != 1:
        raise CamcalError(f"{what} pattern {pattern!r} needs exactly one frame number placeholder like %04d or %d")
    frame_format(pattern)
    return pattern


def frame_path(pattern: str, frame: int) -> Path:
    """``pattern % frame``.

    Examples
    --------
    >>> frame_path("plates/left.%04d.exr", 7).as_posix()
    'plates/left.0007.exr'
    """
    return Path(pattern % frame)


def record_path(output: str | os.PathLike) -> Path:
    """The completion record of an output frame: ``<dir>/.camcal-batch/<name>.json``."""
    output = Path(output)
    return output.parent / RECORD_DIR / f"{output.name}.json"


# -- the job ------------------------------------------------------------------------


@dataclass(frozen=True)
class BatchJob:
    """What every frame of a batch needs; small, sent to each worker once.

    Attributes
    ----------
    camera : mapping
        The source camera, in its rig-file form (``Camera.to_dict()``).
    geometry : {"undistort", "rectify"} or None
        The geometric step.
    mode, overscan
        How ``undistort`` chooses the new camera
        (:func:`camcal.geometry.undistort.undistorted_view`).
    colour : mapping or None
        A characterisation fit in its file form (``ColourFit.to_dict()``).
    in_pattern, out_pattern : str
        Frame file patterns with one ``%d`` / ``%04d`` placeholder.
    colour_space : str
        Output space of the colour step (:data:`COLOUR_SPACES`).
    lenses : mapping of int to mapping
        A camera whose lens changes over the rig's frames (a zoom): frame
        number -> ``{"K", "distortion"}`` of every rig frame
        (:meth:`camcal.model.rig.Rig.camera_at_frame`); each frame is
        remapped with its own lens. Empty: one lens for every frame.
    key : str
        SHA-256 (hex) of everything that changes the output pixels (camera,
        geometry, mode, overscan, colour and its space); keys the per-worker
        cache and the resume records.
    """

    camera: Mapping[str, Any]
    geometry: str | None
    mode: str
    overscan: float
    colour: Mapping[str, Any] | None
    in_pattern: str
    out_pattern: str
    colour_space: str = "ACES2065-1"
    lenses: Mapping[int, Mapping[str, Any]] = field(default_factory=dict)
    key: str = field(init=False)

    def __post_init__(self) -> None:
        if self.geometry is not None and self.geometry not in GEOMETRY:
            raise CamcalError(f"unknown geometric step {self.geometry!r}, expected one of: {', '.join(GEOMETRY)}")
        if self.colour_space not in COLOUR_SPACES:
            raise CamcalError(f"unknown colour space {self.colour_space!r}, expected one of: "
                              f"{', '.join(COLOUR_SPACES)}")
        content = {"camera": self.camera, "geometry": self.geometry, "colour": self.colour}
        if self.colour is not None:
            content["colour_space"] = self.colour_space
        if self.geometry == "undistort":
            content.update(mode=self.mode, overscan=self.overscan)
        if self.lenses:
            content["lenses"] = {str(frame): lens for frame, lens in self.lenses.items()}
        text = json.dumps(content, sort_keys=True, separators=(",", ":"))
        object.__setattr__(self, "key", hashlib.sha256(text.encode()).hexdigest())

    def camera_at(self, frame: int | None) -> Mapping[str, Any]:
        """The camera (file form) of ``frame``: with that frame's lens where :attr:`lenses` has one."""
        lens = self.lenses.get(frame) if frame is not None else None
        return self.camera if lens is None else {**self.camera, "K": lens["K"], "distortion": lens["distortion"]}

    def input_path(self, frame: int) -> Path:
        """The input file of ``frame``."""
        return frame_path(self.in_pattern, frame)

    def output_path(self, frame: int) -> Path:
        """The output file of ``frame``."""
        return frame_path(self.out_pattern, frame)


def make_job(
    rig: str | os.PathLike | Rig,
    camera: str,
    in_pattern: str,
    out_pattern: str,
    geometry: str | None = None,
    colour: str | os.PathLike | ColourFit | None = None,
    mode: str = "crop",
    overscan: float = 1.1,
    colour_space: str = "ACES2065-1",
) -> BatchJob:
    """Check a batch's inputs and describe it as a :class:`BatchJob`.

    Parameters
    ----------
    rig : path or Rig
        The rig file (or rig) holding ``camera``.
    camera : str
        Name of the camera whose plates these are.
    in_pattern, out_pattern : str
        File patterns with one ``%d`` / ``%04d`` (or ``####``: one ``#`` per
        digit); same image format (the outputs keep the inputs' bit depth).
    geometry : {"undistort", "rectify"} or None
        ``rectify`` needs the camera's ``rectification`` (``camcal rectify``).
    colour : path or ColourFit, optional
        A characterisation ``*.colour.json``.
    colour_space : str
        Output space of the colour step: ``ACES2065-1`` (default),
        ``ACEScg``, ``lin Rec.709`` or ``CIE XYZ`` (the fit's XYZ).
    mode, overscan
        See :func:`camcal.geometry.undistort.undistorted_view`.

    Returns
    -------
    BatchJob

    Raises
    ------
    CamcalError
        Missing or invalid rig or fit, unknown camera, a pattern without a
        frame placeholder, input and output of different formats, outputs
        that would overwrite the inputs, or ``rectify`` of a camera whose
        lens changes per frame.
    """
    rig = rig if isinstance(rig, Rig) else Rig.load(rig)
    source = rig.camera(camera)
    if geometry is not None and geometry not in GEOMETRY:
        raise CamcalError(f"unknown geometric step {geometry!r}, expected one of: {', '.join(GEOMETRY)}")
    if geometry == "rectify" and source.rectification is None:
        raise CamcalError(f"camera {camera!r} has no rectification; run `camcal rectify` on the rig first")
    lenses = {}
    if rig.lens_frames(camera) and geometry is not None:  # a zoom: each frame remapped with its lens
        if geometry == "rectify":
            raise CamcalError(f"camera {camera!r}'s lens changes over the rig's frames; its rectification holds one lens")
        for frame in rig.frames:
            at = rig.camera_at_frame(camera, frame.index)
            lenses[frame.index] = {"K": at.K.tolist(), "distortion": at.distortion.to_dict()}
    if geometry == "undistort":
        if mode not in MODES:
            raise CamcalError(f"unknown undistortion mode {mode!r}, expected one of: {', '.join(MODES)}")
        if not np.isfinite(overscan) or overscan < 1.0:
            raise CamcalError(f"overscan must be a number >= 1, got {overscan}")
    if geometry is None and colour is None:
        raise CamcalError("nothing to do: give --undistort, --rectify and/or --colour")
    fit = colour if isinstance(colour, ColourFit) or colour is None else load_fit(colour)
    in_pattern, out_pattern = (printf_pattern(pattern) if "#" in Path(pattern).name else pattern
                               for pattern in (in_pattern, out_pattern))
    _check_pattern(in_pattern, "input")
    _check_pattern(out_pattern, "output")
    if frame_format(in_pattern) != frame_format(out_pattern):
        raise CamcalError(f"output format {Path(out_pattern).suffix!r} differs from the input's "
                          f"{Path(in_pattern).suffix!r}; outputs keep the inputs' format and bit depth")
    if os.path.abspath(in_pattern) == os.path.abspath(out_pattern):
        raise CamcalError(f"the output pattern {out_pattern!r} would overwrite the input frames")
    if fit is not None:
        fit_processor(fit, colour_space)  # a fit the exporter refuses, or an unknown space, fails here, not per frame
    return BatchJob(
        camera=source.to_dict(), geometry=geometry, mode=mode, overscan=float(overscan),
        colour=None if fit is None else fit.to_dict(), in_pattern=in_pattern, out_pattern=out_pattern,
        colour_space=colour_space,
        lenses=lenses,
    )


# -- what a worker builds once ------------------------------------------------------


class ColourStep:
    """Camera code values to an output space, for whole images: the fit's OCIO CPU processor.

    Parameters
    ----------
    fit : ColourFit
        A characterisation (``*.colour.json``).
    space : str
        Output space (:data:`COLOUR_SPACES`).

    Notes
    -----
    One path, :func:`camcal.colour.export.ocio_fit.fit_processor`: the OCIO
    CPU processor of the fit's exported transform (linearisation, model,
    matrix to ``space``), exact for a ``matrix3x3`` fit, the baked
    log-chromaticity Lut3D otherwise (``kind`` and ``bake_error`` say
    which). ``numpy`` evaluation of the fit (``fit.apply_codes``) stays the
    reference the bake is checked against.
    """

    def __init__(self, fit: ColourFit, space: str = "ACES2065-1") -> None:
        self.fit = fit
        self.processor = fit_processor(fit, space)

    @property
    def kind(self) -> str:
        """``"matrix"`` (exact) or ``"lut3d"`` (baked)."""
        return self.processor.kind

    def apply(self, rgb: NDArray) -> NDArray[np.float32]:
        """``(H, W, 3)`` code values in [0, 1] (R, G, B order) -> ``(H, W, 3)`` float32 in the output space."""
        return self.processor.apply(rgb, in_place=True)


class FrameProcessor:
    """The per-worker state of a job: maps and colour step, built once, applied per frame.

    Parameters
    ----------
    job : BatchJob
    frame : int, optional
        The frame whose lens the maps are of (:meth:`BatchJob.camera_at`).

    Attributes
    ----------
    camera : Camera
    maps : RemapMaps or None
        ``undistort``: :func:`camcal.geometry.undistort.make_undistorter`'s
        maps; ``rectify``: ``build_maps(camera, H, rectified size)``.
    colour : ColourStep or None
    build_id : str
        Unique per construction (tests count constructions with it).
    """

    def __init__(self, job: BatchJob, frame: int | None = None) -> None:
        self.camera = Camera.from_dict(job.camera_at(frame))
        self.maps: RemapMaps | None = None
        if job.geometry == "undistort":
            self.maps = make_undistorter(self.camera, job.mode, job.overscan).maps
        elif job.geometry == "rectify":
            rect = self.camera.rectification
            self.maps = build_maps(self.camera, rect.H, rect.image_size)
        self.colour = None if job.colour is None else ColourStep(ColourFit.from_dict(dict(job.colour)),
                                                                  job.colour_space)
        self.build_id = uuid.uuid4().hex

    def apply(self, frame: ImageFrame) -> ImageFrame:
        """Colour-correct then remap one frame; same channels, type and metadata."""
        width, height = self.camera.image_size
        if frame.size != (width, height):
            raise CamcalError(f"the frame is {frame.size[0]}x{frame.size[1]} px but camera "
                              f"{self.camera.name!r} is {width}x{height}")
        pixels = frame.pixels
        integer = np.issubdtype(pixels.dtype, np.integer)
        if self.colour is not None:
            scale = float(np.iinfo(pixels.dtype).max) if integer else 1.0
            rgb = [frame.channel_index(name) for name in ("R", "G", "B")]
            pixels = pixels.astype(np.float32)  # a new array: the colour step works in place on it
            if rgb == [0, 1, 2] and pixels.shape[2] == 3:
                np.divide(pixels, np.float32(scale), out=pixels)
                self.colour.apply(pixels)
            else:
                pixels[:, :, rgb] = self.colour.apply(pixels[:, :, rgb] / np.float32(scale))
        if self.maps is not None:
            warped = self.maps.apply(pixels)
            pixels = warped[:, :, None] if warped.ndim == 2 else warped
        if self.colour is not None and integer:
            pixels = np.rint(np.clip(pixels, 0.0, 1.0) * scale).astype(frame.pixels.dtype)
        return frame.with_pixels(pixels)


_PROCESSORS: dict[str, FrameProcessor] = {}
_PROCESSORS_LOCK = threading.Lock()


def _processor(job: BatchJob, frame: int) -> FrameProcessor:
    """The cached processor of ``job`` (of ``frame``'s lens, with per-frame lenses) in this process, thread-safe."""
    lens = job.lenses.get(frame)
    key = job.key if lens is None else job.key + json.dumps(lens, sort_keys=True)
    with _PROCESSORS_LOCK:
        processor = _PROCESSORS.get(key)
        if processor is None:
            while len(_PROCESSORS) >= _CACHE_SIZE:
                _PROCESSORS.pop(next(iter(_PROCESSORS)))
            processor = _PROCESSORS[key] = FrameProcessor(job, frame)
        return processor


# -- one frame ------------------------------------------------------------------------


@dataclass(frozen=True)
class FrameResult:
    """A frame written.

    Attributes
    ----------
    frame : int
    output : str
        The written file.
    seconds : float
        Read, process and write time on the worker.
    worker : str
        ``host:pid`` of the process that did it.
    processor : str
        ``build_id`` of the :class:`FrameProcessor` used.
    run : str
        Id of the :func:`run_batch` call.
    """

    frame: int
    output: str
    seconds: float
    worker: str
    processor: str
    run: str


@dataclass(frozen=True)
class FrameFailure:
    """A frame that failed after its retries: its number and the last error."""

    frame: int
    message: str


def process_frame(frame: int, job: BatchJob, run: str = "") -> FrameResult:
    """Read, process and write one frame, then its completion record (a Dask task).

    Parameters
    ----------
    frame : int
    job : BatchJob
    run : str
        Id of the run, kept in the record.

    Returns
    -------
    FrameResult

    Raises
    ------
    CamcalError
        ``"frame N: <what went wrong>"``; nothing is written for the frame.
    """
    start = time.perf_counter()
    target = job.output_path(frame)
    try:
        processor = _processor(job, frame)
        written = write_frame(target, processor.apply(read_frame(job.input_path(frame))))
    except CamcalError as error:
        raise CamcalError(f"frame {frame}: {error}") from None
    stat = written.stat()
    worker = f"{socket.gethostname()}:{os.getpid()}"
    write_json(record_path(written), {
        "format": _RECORD_FORMAT, "version": 1, "job": job.key, "frame": frame, "output": written.name,
        "bytes": stat.st_size, "mtime_ns": stat.st_mtime_ns, "run": run, "worker": worker,
        "processor": processor.build_id,
    })
    return FrameResult(frame, str(written), time.perf_counter() - start, worker, processor.build_id, run)


def _is_complete(job: BatchJob, frame: int) -> bool:
    output = job.output_path(frame)
    try:
        record = read_json(record_path(output), "batch record")
        stat = output.stat()
    except (CamcalError, OSError):
        return False
    return (isinstance(record, dict) and record.get("format") == _RECORD_FORMAT
            and record.get("job") == job.key and record.get("frame") == frame
            and record.get("bytes") == stat.st_size and record.get("mtime_ns") == stat.st_mtime_ns)


def completed_frames(job: BatchJob, frames: Sequence[int]) -> tuple[int, ...]:
    """Frames whose output exists and was written by this job, unchanged since (see the module docstring)."""
    return tuple(frame for frame in frames if _is_complete(job, frame))


def _remove_stale_temporaries(job: BatchJob, frames: Sequence[int]) -> None:
    """Temporary files killed writers left for these frames' outputs and records (camcal's own names only)."""
    outputs = [job.output_path(frame) for frame in frames]
    remove_stale_temporaries(outputs + [record_path(output) for output in outputs])


# -- the run --------------------------------------------------------------------------


@dataclass(frozen=True)
class BatchReport:
    """The outcome of :func:`run_batch`.

    Attributes
    ----------
    frames : tuple of int
        Every frame asked for.
    written : tuple of FrameResult
        Frames written by this run, by frame number.
    skipped : tuple of int
        Frames already complete (``resume``), not redone.
    failed : tuple of FrameFailure
        Frames that failed after their retries, by frame number.
    seconds : float
        Wall time of the processing (cluster start included).
    n_workers : int
        Workers of the cluster.
    """

    frames: tuple[int, ...]
    written: tuple[FrameResult, ...]
    skipped: tuple[int, ...]
    failed: tuple[FrameFailure, ...]
    seconds: float
    n_workers: int

    @property
    def ok(self) -> bool:
        """True when no frame failed."""
        return not self.failed

    @property
    def frames_per_s(self) -> float:
        """Frames written per second of wall time."""
        return len(self.written) / self.seconds if self.seconds > 0 else 0.0

    def summary(self) -> str:
        """Counts, rate and the failed frames by number, for people."""
        lines = [f"wrote {len(self.written)} / {len(self.frames)} frames in {self.seconds:.1f} s "
                 f"({self.frames_per_s:.2f} frames/s on {self.n_workers} worker(s))"]
        if self.skipped:
            lines.append(f"skipped {len(self.skipped)} frame(s) already complete")
        if self.failed:
            lines.append(f"FAILED {len(self.failed)} frame(s): {', '.join(str(f.frame) for f in self.failed)}")
            lines.extend(f"  {failure.message}" for failure in self.failed)
        return "\n".join(lines)


def run_batch(
    job: BatchJob,
    frames: Sequence[int],
    *,
    workers: int | None = None,
    scheduler: str | None = None,
    client: Any = None,
    resume: bool = False,
    retries: int = 2,
    progress: bool = True,
) -> BatchReport:
    """Process ``frames`` of ``job`` on Dask, one task per frame.

    Parameters
    ----------
    job : BatchJob
    frames : sequence of int
    workers : int, optional
        Worker processes of the embedded ``distributed.LocalCluster``
        (one thread each; default: one per core).
    scheduler : str, optional
        Address of a running Dask scheduler (``tcp://host:8786``) to use
        instead; its workers must see the input and output paths.
    client : distributed.Client, optional
        An existing client to use (neither cluster is created).
    resume : bool
        Skip frames already complete (:func:`completed_frames`).
    retries : int
        Dask's automatic retries of a failed frame before it is reported.
    progress : bool
        Draw a progress line (:class:`camcal.base.progress.Progress`) on stderr.

    Returns
    -------
    BatchReport
        Written, skipped and failed frames; a failed frame does not stop
        the others.

    Raises
    ------
    CamcalError
        No frames, input frames missing (named, by runs of frame numbers),
        or the scheduler cannot be reached (nothing is written then).
    """
    frames = tuple(int(frame) for frame in frames)
    if not frames:
        raise CamcalError("no frames to process")
    if retries < 0:
        raise CamcalError(f"retries must be >= 0, got {retries}")
    outside = [frame for frame in frames if job.lenses and frame not in job.lenses]
    if outside:
        raise CamcalError(f"frame(s) {', '.join(map(str, outside[:10]))} are not in the rig, whose lens changes per "
                          "frame: no lens for them")
    skipped = completed_frames(job, frames) if resume else ()
    done = set(skipped)
    todo = [frame for frame in frames if frame not in done]
    if todo:
        sequence_paths(job.in_pattern, todo)  # every input there, else the missing frames named, nothing written
    start = time.perf_counter()
    written: list[FrameResult] = []
    failed: list[FrameFailure] = []
    n_workers = 0
    if todo:
        _remove_stale_temporaries(job, todo)
        try:
            n_workers = _run(job, todo, written, failed, workers, scheduler, client, retries, progress)
        finally:  # after the cluster: what workers killed during this run (or with it) left
            _remove_stale_temporaries(job, todo)
    return BatchReport(
        frames=frames,
        written=tuple(sorted(written, key=lambda r: r.frame)),
        skipped=tuple(skipped),
        failed=tuple(sorted(failed, key=lambda f: f.frame)),
        seconds=time.perf_counter() - start,
        n_workers=n_workers,
    )


def _run(job: BatchJob, todo: list[int], written: list[FrameResult], failed: list[FrameFailure],
         workers: int | None, scheduler: str | None, client: Any, retries: int, progress: bool) -> int:
    """Send ``todo`` to Dask, collect results into ``written`` and ``failed``; the number of workers."""
    run = uuid.uuid4().hex
    bar = Progress(len(todo), label="batch", unit="frames", enabled=progress)
    owned = contextlib.nullcontext(client) if client is not None else dask_client(workers, scheduler)
    with owned as dask:
        from distributed import as_completed

        n_workers = len(dask.scheduler_info(n_workers=-1)["workers"])
        # absolute patterns: a farm's workers do not share the client's working directory
        remote = replace(job, in_pattern=os.path.abspath(job.in_pattern),
                         out_pattern=os.path.abspath(job.out_pattern))
        futures = dask.map(process_frame, todo, job=remote, run=run, retries=retries, pure=False)
        frame_of = {future.key: frame for future, frame in zip(futures, todo)}
        for future in as_completed(futures):
            if future.status == "finished":
                written.append(future.result())
                bar.advance()
            else:
                error = future.exception()
                message = str(error) if isinstance(error, CamcalError) else f"{type(error).__name__}: {error}"
                frame = frame_of[future.key]
                failed.append(FrameFailure(frame, message if message.startswith("frame ") else f"frame {frame}: {message}"))
                bar.advance(failed=True)
            future.release()
    bar.close()
    return n_workers
