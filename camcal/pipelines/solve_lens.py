"""The lens of a solve taken from a grid calibration (``solve --intrinsics grid.rig.json``).

A lens calibrated on a grid shot on the day (``calibrate board``) is held
through the whole solve, or refined under its calibration as a prior:

- the plate's size against the grid's: the same size is used as is; the
  same aspect at another size (a proxy, a half-resolution plate) scales
  ``K`` (and a division lens' pixel-unit terms) uniformly, said in one line;
  anything else (a crop, another aspect, an anamorphic squeeze) is one
  error naming both sizes: a crop's offset or a pixel aspect cannot be
  inferred from sizes alone, and a guess would bend every frame;
- a rig whose frames carry a lens per frame (a zoom or a refocus,
  ``camcal lens PROFILE --metadata``) gives each plate frame the lens of
  the rig's frame of the same number (the last number in its file name;
  a plate frame without one is an error naming the frames), held: COLMAP
  gets one camera per plate frame, each held at its lens, and the solved
  rig carries the lenses in its frames (a one-camera solve, ``fixed`` only);
- COLMAP's cameras take the lens before mapping (its model and parameters,
  with ``has_prior_focal_length``), and its mapper holds them
  (:func:`hold_in_database`, :func:`camcal.pipelines.solve_colmap.map_images`);
- camcal's bundle adjustment then holds them (``fixed``) or puts a Gaussian
  prior on each calibrated intrinsic with the grid's sigma (``prior``:
  :func:`lens_priors`, a diagonal prior: the correlations between the
  grid's parameters are not carried) and says how far each moved, in the
  grid's sigmas (:func:`drift_lines`).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from fractions import Fraction

from camcal.base.errors import CamcalError
from camcal.base.frame_ranges import frame_runs
from camcal.geometry.bundle import PriorSpec
from camcal.model.colmap import camera_to_colmap
from camcal.model.distortion import Distortion
from camcal.model.rig import Camera, Rig
from camcal.model.rig_frames import Lens

__all__ = ["LENS_MODES", "PRIOR_NAMES", "GridLens", "drift_lines", "grid_lens", "hold_in_database", "lens_priors",
           "scaled_camera"]

#: ``fixed``: the grid's lens held; ``prior``: refined under the grid's sigmas.
LENS_MODES = ("fixed", "prior")
#: intrinsics a prior can be put on (:class:`camcal.geometry.bundle.PriorSpec`), in camcal's names.
PRIOR_NAMES = ("fx", "fy", "cx", "cy", "lambda", "k1", "k2", "p1", "p2")
#: lens models whose terms act on normalised coordinates (unchanged by a uniform scale of the image).
_NORMALISED = ("none", "polynomial", "opencv", "kannala-brandt", "kannala-brandt-thin-prism")


@dataclass(frozen=True)
class GridLens:
    """The grid's lens for each camera of the solve, at the plate's size.

    Attributes
    ----------
    cameras : dict of str to Camera
        Solve camera name -> the grid camera (intrinsics and lens only matter), at the plate's size.
    mode : {"fixed", "prior"}
    sigmas : dict of str to dict of str to float
        Solve camera name -> the grid's sigma of each intrinsic, at the plate's size (camcal's names).
    lines : tuple of str
        What was taken from where (one line per camera; the scale when there is one).
    lenses : dict of str to Lens
        A zoom or a refocus: each image of the solve (COLMAP's name, ``camera/<k>.<suffix>``) -> its frame's
        lens, at the plate's size; empty for one lens per camera.
    """

    cameras: dict[str, Camera]
    mode: str
    sigmas: dict[str, dict[str, float]]
    lines: tuple[str, ...]
    lenses: dict[str, Lens] = field(default_factory=dict)

    def camera_of(self, image: str) -> Camera:
        """The lens of one image of the solve (COLMAP's name): its frame's, or its camera's."""
        camera = self.cameras[image.split("/", 1)[0]]
        lens = self.lenses.get(image)
        return camera if lens is None else dataclasses.replace(camera, K=lens.K, distortion=lens.distortion)


def scaled_camera(camera: Camera, size: tuple[int, int]) -> tuple[Camera, float]:
    """``camera`` at another image size of the same aspect, and the scale; any other size is an error.

    Notes
    -----
    With pixel (0, 0) at the centre of the top-left pixel, a uniform scale
    ``s`` of the image maps ``u`` to ``s (u + 0.5) - 0.5``: ``fx, fy`` and
    the skew scale by ``s``, ``cx' = s (cx + 0.5) - 0.5``. Lens terms on
    normalised coordinates do not change; the division model's ``lambda``
    (pixels^-2) becomes ``lambda / s^2`` and its centre moves like the
    principal point.
    """
    grid_w, grid_h = camera.image_size
    width, height = size
    if (width, height) == (grid_w, grid_h):
        return camera, 1.0
    if width * grid_h != height * grid_w:
        raise CamcalError(f"camera {camera.name!r}: the plate is {width}x{height} but the grid's lens was calibrated "
                          f"at {grid_w}x{grid_h}: another aspect (a crop, or a pixel aspect) cannot be inferred from "
                          "the sizes; calibrate at the plate's format, or crop / scale the plate to the grid's")
    s = float(Fraction(width, grid_w))
    model = camera.distortion.model
    if camera.distortion.has_correction or model not in _NORMALISED + ("division",):
        raise CamcalError(f"camera {camera.name!r}: the plate is {width}x{height}, the grid {grid_w}x{grid_h}, and "
                          f"a {model} lens{' with a correction field' if camera.distortion.has_correction else ''} "
                          "cannot be scaled: calibrate at the plate's size")
    K = camera.K.copy()
    K[:2, :] *= s
    K[0, 2] += 0.5 * s - 0.5
    K[1, 2] += 0.5 * s - 0.5
    distortion = camera.distortion
    if model == "division":
        params = {**distortion.params, "lambda": distortion.params["lambda"] / s ** 2}
        centre = None if distortion.center is None else tuple(s * (v + 0.5) - 0.5 for v in distortion.center)
        distortion = Distortion("division", params, center=centre)
    return dataclasses.replace(camera, image_size=(width, height), K=K, distortion=distortion), s


def _scaled_sigmas(camera: Camera, s: float) -> dict[str, float]:
    """The grid camera's sigmas of :data:`PRIOR_NAMES` at a scale ``s`` (pixels scale, lambda by ``1 / s^2``)."""
    sigma = dict(camera.quality.get("sigma", {}) or {})
    scale = {"fx": s, "fy": s, "cx": s, "cy": s, "lambda": 1.0 / s ** 2}
    return {name: float(sigma[name]) * scale.get(name, 1.0) for name in PRIOR_NAMES if name in sigma}


def grid_lens(grid: Rig, sizes: dict[str, tuple[int, int]], mode: str = "fixed", source: str = "the grid",
              frame_numbers: dict[str, int | None] | None = None) -> GridLens:
    """The grid's lens for each camera of the solve (matched by name; one camera each: the one), at the plate's size.

    Parameters
    ----------
    grid : Rig
        The grid calibration (``calibrate board``).
    sizes : dict of str to (int, int)
        Solve camera name -> its images' size.
    mode : {"fixed", "prior"}
    source : str
        How to name the grid in messages (its file).
    frame_numbers : dict of str to int or None, optional
        Each image of the solve (COLMAP's name) -> its plate frame number (None: its file name has none): a rig
        with a lens per frame gives each image the lens of the frame of that number.
    """
    if mode not in LENS_MODES:
        raise CamcalError(f"unknown intrinsics mode {mode!r}, expected one of: {', '.join(LENS_MODES)}")
    names = [camera.name for camera in grid.cameras]
    cameras, sigmas, lines, lenses = {}, {}, [], {}
    for name, size in sizes.items():
        if name in names:
            camera = grid.camera(name)
        elif len(names) == 1 and len(sizes) == 1:
            camera = grid.cameras[0]
        else:
            raise CamcalError(f"{source} has no camera named {name!r} (it has: {', '.join(names)})")
        if grid.lens_frames(camera.name):
            if mode != "fixed" or len(sizes) != 1 or frame_numbers is None:
                raise CamcalError(f"{source}: camera {camera.name!r} has a lens per frame (a zoom or a refocus): "
                                  "those lenses can only be held (--intrinsics-mode fixed), on a one-camera solve")
            mine = _lenses_per_image(grid, camera, size, frame_numbers, source)
            lenses.update(mine)
            focals = sorted(lens.K[0, 0] for lens in mine.values())
            lines.append(f"{name}: the lens of each frame from {source} (camera {camera.name!r}, "
                         f"{camera.distortion.model}, {len(mine)} frames, fx {focals[0]:.2f}-{focals[-1]:.2f} px) held")
        camera_to_colmap(camera)  # a lens COLMAP cannot carry is refused here, before any work
        scaled, s = scaled_camera(camera, size)
        if mode == "prior":
            sigmas[name] = _scaled_sigmas(camera, s)
            if not sigmas[name]:
                raise CamcalError(f"{source}: camera {camera.name!r} has no sigmas (quality.sigma) to make a prior "
                                  "of: hold its lens (--intrinsics-mode fixed) or calibrate it again")
        cameras[name] = dataclasses.replace(scaled, name=name)
        if lenses:
            continue
        how = "held" if mode == "fixed" else "refined under its sigmas as a prior"
        lines.append(f"{name}: the lens of {source} (camera {camera.name!r}, {camera.distortion.model}, "
                     f"fx {scaled.K[0, 0]:.2f} px) {how}"
                     + ("" if s == 1.0 else f"; K scaled x{s:g} from its {camera.image_size[0]}x"
                        f"{camera.image_size[1]} to the plate's {size[0]}x{size[1]}"))
    return GridLens(cameras, mode, sigmas, tuple(lines), lenses)


def _lenses_per_image(grid: Rig, camera: Camera, size: tuple[int, int], frame_numbers: dict[str, int | None],
                      source: str) -> dict[str, Lens]:
    """Each image's lens: the rig's frame of the image's number, at the plate's size; missing frames named."""
    by_frame = {frame.index: frame.lenses[camera.name] for frame in grid.frames if camera.name in frame.lenses}
    unnumbered = sorted(image for image, number in frame_numbers.items() if number is None)
    if unnumbered:
        raise CamcalError(f"{source} has a lens per frame, but plate image {unnumbered[0]!r} has no frame number in "
                          "its name to match one by")
    missing = sorted({number for number in frame_numbers.values() if number not in by_frame})
    if missing:
        raise CamcalError(f"{source} has no lens of camera {camera.name!r} for plate frames "
                          f"{', '.join(frame_runs(missing))} (it has frames {', '.join(frame_runs(sorted(by_frame)))})")
    lenses = {}
    for image, number in frame_numbers.items():
        lens = by_frame[number]
        scaled, _ = scaled_camera(dataclasses.replace(camera, K=lens.K, distortion=lens.distortion), size)
        camera_to_colmap(scaled)
        lenses[image] = Lens(scaled.K, scaled.distortion, lens.focal_mm, lens.focus_m)
    return lenses


def hold_in_database(pycolmap, database, lens: GridLens) -> None:
    """Give each COLMAP camera of a freshly extracted ``database`` the grid's lens (model, parameters, prior focal).

    A camera is named by the folder of its images (``camera/<k>.png``); with a lens per frame
    (:attr:`GridLens.lenses`), each image has a camera of its own (extracted one camera per image), which takes
    its frame's lens.
    """
    db = pycolmap.Database.open(database)
    try:
        image_of = {image.camera_id: image.name for image in db.read_all_images()}
        for camera in db.read_all_cameras():
            grid = lens.camera_of(image_of[camera.camera_id])
            colmap = camera_to_colmap(grid)
            held = pycolmap.Camera.create_from_model_name(camera.camera_id, colmap.model, 1.0, colmap.width,
                                                          colmap.height)
            held.params = list(colmap.params)
            held.has_prior_focal_length = True
            db.update_camera(held)
    finally:
        db.close()


def lens_priors(lens: GridLens) -> tuple[PriorSpec, ...]:
    """A Gaussian prior on each intrinsic the grid measured: its value at the plate's size, its sigma."""
    specs = []
    for name, camera in lens.cameras.items():
        values = {"fx": camera.K[0, 0], "fy": camera.K[1, 1], "cx": camera.K[0, 2], "cy": camera.K[1, 2],
                  **camera.distortion.params}
        for key, sigma in lens.sigmas.get(name, {}).items():
            if key in values and sigma > 0:
                specs.append(PriorSpec(name, key, float(values[key]), sigma, "the grid's calibration"))
    return tuple(specs)


def drift_lines(lens: GridLens, solved: dict[str, Camera]) -> list[str]:
    """How far each prior intrinsic moved from the grid's value, in the grid's sigmas (one line per camera)."""
    lines = []
    for spec_camera, camera in lens.cameras.items():
        if spec_camera not in solved:
            continue
        after = solved[spec_camera]
        moves = []
        for key, sigma in lens.sigmas.get(spec_camera, {}).items():
            before_value, after_value = _value(camera, key), _value(after, key)
            if before_value is not None and after_value is not None and sigma > 0:
                moves.append((abs(after_value - before_value) / sigma, key))
        if moves:
            worst, key = max(moves)
            lines.append(f"{spec_camera}: the lens moved from the grid's by at most {worst:.2f} sigma ({key}; "
                         + ", ".join(f"{k} {v:.2f}" for v, k in moves) + ")")
    return lines


def _value(camera: Camera, key: str) -> float | None:
    """An intrinsic of ``camera`` by its camcal name (None when its lens has no such term)."""
    pixel = {"fx": (0, 0), "fy": (1, 1), "cx": (0, 2), "cy": (1, 2)}
    if key in pixel:
        return float(camera.K[pixel[key]])
    value = camera.distortion.params.get(key)
    return None if value is None else float(value)
