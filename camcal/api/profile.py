"""``camcal.calibrate_profile``: a lens profile over focal length and focus distance, as ``calibrate profile``.

Each lens state (``24mm@1.2m``) is calibrated from its board images by
:func:`camcal.api.board.calibrate_board` (or read from a rig file calibrated
before), with one lens model for all; then every parameter becomes a smooth
surface over the state (:func:`camcal.geometry.lens_profile.fit_profile`).
"""

from __future__ import annotations

import math
import os
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from camcal.base.errors import CamcalError

if TYPE_CHECKING:
    from camcal.api.board import BoardCalibration, CameraInputs
    from camcal.colour.flatfield import FlatField
    from camcal.geometry.board import Board
    from camcal.geometry.lens_profile import StateSuggestion
    from camcal.model.lens_profile import LensProfile, LensState
    from camcal.model.rig import Camera, Rig

__all__ = ["DEFAULT_PROFILE_MODEL", "PROFILE_FORMATS", "TDE_INFINITY_M", "ProfileCalibration", "calibrate_profile",
           "export_profile"]

#: The formats a lens profile exports to (``camcal rig export PROFILE OUT --to FORMAT``).
PROFILE_FORMATS = ("lensfun", "lens-table", "opentrackio", "3de")
#: A lens table's encoder grid: at most this many zoom and focus steps (each at most one per state calibrated
#: between them, with a step between each two).
_TABLE_STEPS = (9, 5)

#: The lens model of ``calibrate profile`` without ``--model`` (``auto`` ranks the models once, on one state).
DEFAULT_PROFILE_MODEL = "polynomial"


@dataclass(frozen=True)
class ProfileCalibration:
    """What :func:`calibrate_profile` found and wrote.

    Attributes
    ----------
    profile : LensProfile
    calibrations : mapping of str to BoardCalibration
        State label -> its board calibration (the states read from rig files have none).
    disagreeing : mapping of str to str
        State label -> why it disagrees with every smooth profile (``k1 12.3 sigma``).
    suggestion : StateSuggestion or None
        With ``suggest``: the state to calibrate next.
    notes : tuple of str
    files : tuple of (Path, str)
    """

    profile: LensProfile
    calibrations: Mapping[str, BoardCalibration] = field(default_factory=dict)
    disagreeing: Mapping[str, str] = field(default_factory=dict)
    suggestion: StateSuggestion | None = None
    notes: tuple[str, ...] = ()
    files: tuple[tuple[Path, str], ...] = ()

    def save(self, path: str | os.PathLike) -> Path:
        """Write the profile file (atomically) and return its path."""
        return self.profile.save(path)

    def lines(self) -> list[str]:
        """What ``calibrate profile`` prints: each state, each surface, the states that disagree, the next state."""
        profile = self.profile
        lines = list(self.notes)
        lines.append(f"lens profile: {len(profile.states)} states, {profile.model} lens, "
                     f"{profile.focal_range[0]:g}-{profile.focal_range[1]:g} mm, focus "
                     + " to ".join("inf" if math.isinf(d) else f"{d:g} m" for d in profile.focus_range))
        for state in profile.states:
            sigma = state.sigma
            lines.append(f"  {state.label}: {state.n_images} images, RMS {state.rms_px:.3f} px, "
                         f"fx {state.params['fx']:.2f} +/- {sigma['fx']:.2f}, principal point "
                         f"({state.params['cx']:.2f}, {state.params['cy']:.2f}) px")
        lines.append("surfaces (degrees chosen by leaving one state out in turn):")
        for name in profile.parameters:
            surface = profile.surfaces[name]
            loso = "no state to hold out" if surface.loso_rms is None else \
                f"left-out RMS {surface.loso_rms:.4g}, sigma x{surface.scale:.3g}"
            lines.append(f"  {name}: {surface.describe()} ({loso})")
        if self.disagreeing:
            lines.append("states that disagree with every smooth profile: " + ", ".join(
                f"{label} ({why})" for label, why in self.disagreeing.items()))
        if self.suggestion is not None:
            from camcal.model.lens_profile import format_state

            s = self.suggestion
            lines.append(f"next state to shoot: {format_state(s.focal_mm, s.focus_m)} (worst projection sigma "
                         f"{s.worst_sigma_px:.3g} px there; at most {s.calibrated_worst_sigma_px:.3g} px at the "
                         "states calibrated)")
        return lines

    def figures(self) -> dict[str, Any]:
        """The figures of ``calibrate profile --json``."""
        profile = self.profile
        figures: dict[str, Any] = {
            "model": profile.model, "image_size": list(profile.image_size),
            "states": {s.label: {"focal_mm": s.focal_mm, "focus_m": None if math.isinf(s.focus_m) else s.focus_m,
                                 "n_images": s.n_images, "rms_px": s.rms_px, "params": dict(s.params),
                                 "sigma": s.sigma} for s in profile.states},
            "surfaces": {name: {"terms": [list(t) for t in surface.terms], "scale": surface.scale,
                                "loso_rms": surface.loso_rms} for name, surface in profile.surfaces.items()},
            "disagreeing": dict(self.disagreeing),
        }
        if self.suggestion is not None:
            s = self.suggestion
            figures["suggested"] = {"focal_mm": s.focal_mm, "focus_m": None if math.isinf(s.focus_m) else s.focus_m,
                                    "worst_sigma_px": s.worst_sigma_px,
                                    "calibrated_worst_sigma_px": s.calibrated_worst_sigma_px}
        return figures


def _is_rig_file(value: object) -> bool:
    return isinstance(value, (str, os.PathLike)) and os.fspath(value).endswith(".rig.json")


def _state_from_camera(label: str, focal: float, focus: float, camera: Camera, covariance_of: Callable[[str], Any],
                       n_images: int, rms_px: float) -> LensState:
    """A :class:`LensState` of a calibrated camera; ``covariance_of(name)`` is the covariance row source."""
    from camcal.model.lens_profile import INTRINSIC_NAMES, LensState

    K = camera.K
    params = dict(zip(INTRINSIC_NAMES, (K[0, 0], K[1, 1], K[0, 2], K[1, 2])))
    params.update(camera.distortion.params)
    names = list(params)
    covariance = covariance_of(names)
    return LensState(label, focal, focus, {k: float(v) for k, v in params.items()}, covariance, n_images, rms_px)


def _covariance_from_fit(calibration: BoardCalibration, camera: Camera) -> Callable:
    """The covariance of the named parameters from a board fit: the camera's own
    (:func:`_carried_covariance`), else the fit's rows (``camera.fx`` ...), else its sigmas."""
    result = calibration.calibration
    index = {name: i for i, name in enumerate(result.parameter_names)}

    def covariance(names: list[str]):
        keys = [f"{camera.name}.{name}" for name in names]
        carried = _carried_covariance(camera, names)
        if carried is None and all(key in index for key in keys):
            rows = [index[key] for key in keys]
            return result.covariance[np.ix_(rows, rows)]
        return carried if carried is not None else _covariance_from_camera(camera, "the calibration")(names)

    return covariance


def _carried_covariance(camera: Camera, names: list[str]) -> np.ndarray | None:
    """The rows ``names`` of the camera's ``quality.covariance``; None when it does not hold them all.

    That covariance is what the camera's projection sigma uses: a board fit of at least 5 views scales it by the
    design effect of its delete-one-view jackknife (:mod:`camcal.geometry.view_jackknife`: the corners' errors
    are correlated within a view), and it keeps the parameters' correlations (fx with fy, k1 with k2), which a
    diagonal of ``quality.sigma`` drops. The fit's own ``sigma^2 (J^T J)^-1`` has not got the design effect."""
    carried = camera.quality.covariance
    if carried is None or not all(name in carried.names for name in names):
        return None
    rows = [carried.names.index(name) for name in names]
    return carried.array[np.ix_(rows, rows)]


def _covariance_from_camera(camera: Camera, where: str) -> Callable:
    """The covariance of the named parameters as the camera carries it (:func:`_carried_covariance`), else a
    diagonal of its sigmas."""

    def covariance(names: list[str]):
        carried = _carried_covariance(camera, names)
        if carried is not None:
            return carried
        sigma = camera.quality.sigma
        missing = [name for name in names if name not in sigma]
        if missing:
            raise CamcalError(f"{where}: camera {camera.name!r} has no sigma for {', '.join(missing)} (a profile "
                              "weighs each state by its uncertainty; calibrate it with camcal calibrate board)")
        return np.diag([sigma[name] ** 2 for name in names])

    return covariance


def _check_alike(label: str, camera: Camera, earlier: list, sizes: Mapping[str, tuple[int, int]]) -> None:
    """A state's camera has the image size and the lens model (and its parameters) of the first state's, and no
    correction field (a profile interpolates parameters, not fields)."""
    if camera.distortion.has_correction:
        raise CamcalError(f"--state {label}: its lens has a correction field ({camera.distortion.model}+spline), which "
                          "a profile cannot interpolate: name a --model without +spline")
    if not earlier:
        return
    first, first_model = earlier[0]
    size, first_size = camera.image_size, sizes[first.label]
    if size != first_size:
        raise CamcalError(f"--state: {label} has images of {size[0]}x{size[1]} px, {first.label} "
                          f"{first_size[0]}x{first_size[1]} px (one camera format per profile)")
    names = list(camera.distortion.params)
    if camera.distortion.model != first_model or names != list(first.params)[4:]:
        raise CamcalError(f"--state: {label} has a {camera.distortion.model} lens ({', '.join(names)}), "
                          f"{first.label} a {first_model} lens ({', '.join(list(first.params)[4:])}) (one lens "
                          "model per profile)")


def calibrate_profile(
    states: Mapping[str, CameraInputs | Rig | BoardCalibration] | None,
    board: str | Board,
    *,
    states_from: tuple[str, str | os.PathLike] | None = None,
    model: str = DEFAULT_PROFILE_MODEL,
    holdout: str | float | None = None,
    cache: str | os.PathLike | bool = True,
    workers: int | None = None,
    force: bool = False,
    suggest: bool = False,
    out: str | os.PathLike | None = None,
    progress: bool = True,
    log: Callable[[str], None] | None = None,
) -> ProfileCalibration:
    """A lens profile from board images at several lens states (``camcal calibrate profile``).

    Parameters
    ----------
    states : mapping of str to (glob, video, image files, rig file, Rig or BoardCalibration)
        Lens state -> its board images (as :func:`camcal.calibrate_board` takes them), or a one-camera
        ``*.rig.json`` or :func:`camcal.calibrate_board` result calibrated at it, e.g.
        ``{"24mm@1.2m": "grids/24_1.2/*.jpg", "35mm@inf": "grids/35_inf/*.jpg"}``
        (:func:`camcal.model.lens_profile.parse_state`: ``FOCALmm@FOCUSm``, ``@inf``); None with ``states_from``.
    board : str or Board
        The board every state's images show (as :func:`camcal.calibrate_board`).
    states_from : (str, path), optional
        Instead of ``states``: ``("folders", DIR)`` (a sub-folder per state, named ``24mm@1.2m`` or
        ``24mm_1.2m``), ``("exif", GLOB)`` (the images grouped by their EXIF ``FocalLength`` and
        ``SubjectDistance``) or ``("csv", FILE)`` (``image,focal_mm,focus_m``)
        (:func:`camcal.pipelines.lens_states.states_from`).
    model : str
        The one lens model of every state (:func:`camcal.calibrate_board`'s names); ``auto`` ranks the models
        once, on the state of the shortest focal length (the most distortion), and fits that model everywhere.
    holdout : str or float, optional
        Each state's held-out views (as :func:`camcal.calibrate_board`).
    cache, workers, force, progress
        As :func:`camcal.calibrate_board`, for each state.
    suggest : bool
        Also find the lens state to calibrate next: where the profile's worst projection sigma is largest.
    out : path, optional
        The ``*.profile.json`` to write (atomically, after every check).
    log : callable, optional
        Receives each line printed while it runs (e.g. ``print``).

    Returns
    -------
    ProfileCalibration

    Raises
    ------
    CamcalError
        Fewer than 2 states, a state label that is not ``FOCALmm@FOCUSm``, duplicate states, states of different
        image sizes, lens models or boards, or a state's calibration refused by its quality gate; both or neither
        of ``states`` and ``states_from``, a folder name that is not a state, images without the EXIF of their
        state, a bad CSV, or a state with fewer than 3 images; nothing is written then.

    Examples
    --------
    >>> import camcal  # doctest: +SKIP
    >>> result = camcal.calibrate_profile({"24mm@1.2m": "grids/24_1.2/*.jpg", "35mm@1.2m": "grids/35_1.2/*.jpg",
    ...                                    "50mm@inf": "grids/50_inf/*.jpg"}, "chessboard:9x6:0.03",
    ...                                   out="lens.profile.json")  # doctest: +SKIP
    """
    from camcal.api.board import BoardCalibration, calibrate_board
    from camcal.geometry.board import Board, parse_board
    from camcal.geometry.lens_profile import fit_profile, suggest_state
    from camcal.model.lens_profile import LensProfile, parse_state
    from camcal.model.rig import Rig, make_provenance

    say = log or (lambda line: None)
    board = board if isinstance(board, Board) else parse_board(board)
    if (states is None) == (states_from is None):
        raise CamcalError("give the lens states with --state or with --states-from (one of them)")
    if states_from is not None:
        from camcal.pipelines.lens_states import states_from as read_states

        source, where = states_from
        states = read_states(source, where)
        say(f"--states-from {source}: " + ", ".join(f"{label} ({len(paths)} images)"
                                                   for label, paths in states.items()))
    if len(states) < 2:
        raise CamcalError(f"--state: a lens profile needs at least 2 lens states, got {len(states)}")
    parsed = {label: parse_state(label) for label in states}
    seen: dict[tuple[float, float], str] = {}
    for label, key in parsed.items():
        if key in seen:
            raise CamcalError(f"--state: {seen[key]} and {label} are the same lens state (one set of images per "
                              "state)")
        seen[key] = label
    order = sorted(states, key=lambda label: parsed[label])
    calibrations, lens_states, sizes, notes = {}, [], {}, []
    chosen_model = model
    for label in order:
        focal, focus = parsed[label]
        value = states[label]
        if isinstance(value, Rig) or _is_rig_file(value):
            rig = value if isinstance(value, Rig) else Rig.load(value)
            where = "the given rig" if isinstance(value, Rig) else os.fspath(value)
            if len(rig.cameras) != 1:
                raise CamcalError(f"--state {label}: {where} has {len(rig.cameras)} cameras; a lens state is one")
            given_board = rig.provenance.get("board")
            if given_board is not None and given_board != board.spec():
                raise CamcalError(f"--state {label}: {where} was calibrated on board {given_board}, not "
                                  f"{board.spec()} (every state on one board)")
            camera = rig.cameras[0]
            _check_alike(label, camera, lens_states, sizes)
            state = _state_from_camera(label, focal, focus, camera, _covariance_from_camera(camera, where),
                                       int(camera.quality.n_views or 0), float(camera.quality.rms_px or 0.0))
            say(f"{label}: read {where}")
        else:
            if isinstance(value, BoardCalibration):
                calibration = value
                if calibration.board.spec() != board.spec():
                    raise CamcalError(f"--state {label}: calibrated on board {calibration.board.spec()}, not "
                                      f"{board.spec()} (every state on one board)")
            else:
                say(f"{label}:")
                calibration = calibrate_board(value, board, model=chosen_model, holdout=holdout, cache=cache,
                                              workers=workers, force=force, progress=progress, log=say)
            if chosen_model == "auto":
                chosen_model = calibration.calibration.model
                notes.append(f"model auto: ranked on {label} (the shortest focal length), {chosen_model} fitted "
                             "at every state")
            camera = calibration.rig.cameras[0]
            _check_alike(label, camera, lens_states, sizes)
            calibrations[label] = calibration
            kept = sum(1 for name, _ in calibration.calibration.images if name == camera.name)
            state = _state_from_camera(label, focal, focus, camera, _covariance_from_fit(calibration, camera), kept,
                                       calibration.rms_px)
        sizes[label] = camera.image_size
        lens_states.append((state, camera.distortion.model))
    first_label = order[0]
    parameters = tuple(lens_states[0][0].params)
    only = [state for state, _ in lens_states]
    fitted = fit_profile(only, parameters)
    profile = LensProfile(lens_states[0][1], sizes[first_label], board.spec(), parameters, tuple(only),
                          fitted.surfaces, make_provenance("calibrate profile", board=board.spec()))
    suggestion = suggest_state(profile) if suggest else None
    files = () if out is None else ((profile.save(out), "profile"),)
    return ProfileCalibration(profile, calibrations, fitted.disagreeing, suggestion, tuple(notes), files)


def export_profile(profile: str | os.PathLike | LensProfile, path: str | os.PathLike, to: str | None = None, *,
                   name: str | None = None, sensor_width_mm: float | None = None,
                   vignetting: Mapping[str, str | os.PathLike | FlatField] | None = None,
                   tca: Mapping[str, CameraInputs] | None = None) -> Any:
    """Write a lens profile for another tool (``camcal rig export lens.profile.json lens.xml --to lensfun``, or
    ``lens.json --to lens-table`` / ``--to opentrackio``, or ``lens.txt --to 3de``).

    lens-table: the profile sampled on a grid of OpenTrackIO's normalised encoders (:mod:`camcal.io.lens_table`).
    opentrackio: the same grid as OpenTrackIO lens samples, Brown-Conrady in mm on the sensor
    (:mod:`camcal.io.opentrackio`; needs ``sensor_width_mm``), the worst state's residual in the result.
    3de: a 3DEqualizer lens file with dynamic distortion (:mod:`camcal.io.tde`): the same grid as a rig with a lens
    per frame, keyed over focal length, focus distance or both (a 2D LUT), each state's refit residual in the
    result; a focus at infinity is keyed at :data:`TDE_INFINITY_M` (3DE keys distances).
    lensfun: one ``<lens>`` with a ``<distortion>`` per focal length calibrated, each the profile's camera at
    that focal length focused at the farthest focus calibrated (Lensfun's lenses do not change with focus), in
    the one Lensfun model (``poly3``, ``poly5``, ``ptlens``) that fits every focal length best, its residual
    in the result's notes (:func:`camcal.io.lensfun.export_states`); with ``vignetting``, a ``pa`` vignetting entry
    per flat field (:mod:`camcal.io.lensfun_vignetting`), fitted about the lens' centre, the largest deviation from
    the flat field it leaves in the notes; with ``tca``, a ``poly3`` TCA entry per focal length
    (:mod:`camcal.io.lensfun_tca`) from colour board images, the corners' residual in the notes.

    Parameters
    ----------
    profile : path or LensProfile
    path : path
        The ``.xml`` (lensfun), ``.json`` (lens-table, opentrackio) or ``.txt`` (3de) to write.
    to : str, optional
        One of :data:`PROFILE_FORMATS` (default: 3de for a ``.txt``, else lensfun).
    name : str, optional
        The lens' ``<model>`` (default: the profile file's name without ``.profile.json``).
    sensor_width_mm : float, optional
        The sensor's active width in mm: required by opentrackio (the profile holds pixels only); 3de: its film
        back (default 36 mm).
    vignetting : mapping of str to (path or FlatField), optional
        lensfun: flat fields (``colour flatfield --out``'s ``*.json``) by the lens state and aperture they were
        shot at, ``FOCALmm@FOCUSm/fN``: ``{"24mm@1.2m/f4": "flat24.json", "50mm@inf/f2.8": "flat50.json"}``;
        each state inside the profile's calibrated range.
    tca : mapping of str to (glob or image files), optional
        lensfun: 8-bit colour images of the profile's board by the focal length they were shot at, ``FOCALmm``:
        ``{"24mm": "tca/24/*.png"}`` (:mod:`camcal.pipelines.lateral_ca`); each inside the calibrated range.

    Returns
    -------
    ExportResult

    Raises
    ------
    CamcalError
        An unknown format, an option another format's, a vignetting state without its aperture or outside the
        calibrated range, given twice, or a flat field of another aspect ratio; a TCA focal length outside the
        range or images without the board or of another size; nothing is written then.
    """
    from dataclasses import replace

    from camcal.geometry.lens_profile import camera_at
    from camcal.io.lensfun import export_states
    from camcal.model.lens_profile import LensProfile

    fmt = to or ("3de" if Path(path).suffix.lower() == ".txt" else "lensfun")
    if fmt not in PROFILE_FORMATS:
        raise CamcalError(f"a lens profile exports to {', '.join(PROFILE_FORMATS)}, not {fmt!r} (export a camera at "
                          "one lens state with camcal lens first)")
    if sensor_width_mm is not None and fmt not in ("opentrackio", "3de"):
        raise CamcalError(f"a sensor width applies to opentrackio and 3de, not {fmt}")
    for option, given in (("--vignetting", vignetting), ("--tca", tca)):
        if given and fmt != "lensfun":
            raise CamcalError(f"{option} applies to lensfun, not {fmt}")
    if fmt == "opentrackio" and sensor_width_mm is None:
        raise CamcalError("an OpenTrackIO lens is in mm on the sensor and a lens profile holds pixels only: give the "
                          "sensor's width (--sensor-width MM)")
    if not isinstance(profile, LensProfile):
        stem = Path(profile).name.removesuffix(".json").removesuffix(".profile")
        profile = LensProfile.load(profile)
    else:
        stem = "lens"
    if fmt == "lens-table":
        return _export_table(profile, Path(path), name or stem)
    if fmt == "opentrackio":
        from camcal.io.opentrackio import LensSample, write_opentrackio_lens

        return write_opentrackio_lens(Path(path), [LensSample(*sample) for sample in _encoder_grid(profile)],
                                      name=name or stem, sensor_width_mm=sensor_width_mm,
                                      focal_range=profile.focal_range, focus_range=profile.focus_range)
    if fmt == "3de":
        return _export_tde(profile, Path(path), name or stem, sensor_width_mm)
    far = profile.focus_range[1]
    focals = sorted({state.focal_mm for state in profile.states})
    flats = _vignetting_states(profile, vignetting or {})
    fringes = _tca_states(profile, tca or {})
    result = export_states([(focal, camera_at(profile, focal, far, f"{focal:g}mm")) for focal in focals], Path(path),
                           name=name or stem, vignetting=flats, tca=fringes)
    focus = "inf" if math.isinf(far) else f"{far:g} m"
    notes = (*result.notes, f"each focal length at the farthest focus calibrated ({focus}): Lensfun's lenses do not "
             "change with focus")
    return replace(result, notes=notes)


def _focal_text(profile: LensProfile) -> str:
    """The calibrated focal lengths: ``24-70 mm`` (``24 mm`` for one)."""
    low, high = profile.focal_range
    return f"{low:g} mm" if low == high else f"{low:g}-{high:g} mm"


def _vignetting_states(profile: LensProfile, flats: Mapping[str, str | os.PathLike | FlatField]) -> list:
    """The :class:`~camcal.io.lensfun_vignetting.VignettingState` of each ``FOCALmm@FOCUSm/fN`` -> flat field, in
    the order given; each state inside the profile's calibrated range, each once."""
    from camcal.colour.flatfield import FlatField
    from camcal.io.flatfield import load_flat_field
    from camcal.io.lensfun_vignetting import VignettingState
    from camcal.model.lens_profile import parse_state

    states, seen = [], {}
    for key, flat in flats.items():
        label, slash, aperture_text = key.rpartition("/")
        try:
            aperture = float(aperture_text[1:]) if slash and aperture_text[:1].lower() == "f" else math.nan
        except ValueError:
            aperture = math.nan
        if not (aperture > 0 and math.isfinite(aperture)):
            raise CamcalError(f"--vignetting {key}: expected FOCALmm@FOCUSm/fN, the lens state and the aperture "
                              "the flat field was shot at (e.g. 24mm@1.2m/f4)")
        focal, focus = parse_state(label)
        (low, high), (near, far) = profile.focal_range, profile.focus_range
        if not (low <= focal <= high and near <= focus <= far):
            raise CamcalError(f"--vignetting {key}: outside the profile's calibrated range ({_focal_text(profile)}, "
                              f"focus {near:g} m to " + ("inf" if math.isinf(far) else f"{far:g} m") + ")")
        if (focal, focus, aperture) in seen:
            raise CamcalError(f"--vignetting: {seen[focal, focus, aperture]} and {key} are the same lens state")
        seen[focal, focus, aperture] = key
        states.append(VignettingState(focal, aperture, focus, flat if isinstance(flat, FlatField)
                                      else load_flat_field(flat)))
    return states


def _tca_states(profile: LensProfile, images: Mapping[str, CameraInputs]) -> list:
    """The :class:`~camcal.io.lensfun_tca.TCAState` of each ``FOCALmm`` -> colour board images: the profile's board
    found in each image and its corners in every channel."""
    from camcal.geometry.board import parse_board
    from camcal.io.lensfun_tca import TCAState
    from camcal.pipelines.lateral_ca import channel_corners_from_files

    states = []
    for key, value in images.items():
        try:
            focal = float(key.strip().removesuffix("mm"))
        except ValueError:
            focal = math.nan
        low, high = profile.focal_range
        if not low <= focal <= high:
            raise CamcalError(f"--tca {key}: expected FOCALmm inside the profile's calibrated range "
                              f"({_focal_text(profile)}), e.g. {low:g}mm")
        found = channel_corners_from_files(value, parse_board(profile.board), option="--tca", name=key)
        states.append(TCAState(focal, found.corners, found.image_size, f"{found.n_used} / {found.n_images} images"))
    return states


#: A profile's focus at infinity as 3DE keys it (3DE's dynamic distortion is a curve over focus distance): 10 km,
#: where the profile's lens is the one at infinity to 1e-4 dioptre.
TDE_INFINITY_M = 1.0e4


def _encoder_grid(profile: LensProfile,
                  infinity_m: float = math.inf) -> list[tuple[float, float, float, float, Camera]]:
    """``(zoom encoder, focus encoder, focal_mm, focus_m, camera)`` on a grid of OpenTrackIO encoders over the
    calibrated range (at most :data:`_TABLE_STEPS`, one step between each two states calibrated); a focus at
    infinity is taken at ``infinity_m``."""
    from camcal.geometry.lens_profile import camera_at

    counts = [min(limit, 2 * len({key(s) for s in profile.states}) - 1)
              for limit, key in zip(_TABLE_STEPS, (lambda s: s.focal_mm, lambda s: s.focus_m))]
    samples = []
    for zoom in np.linspace(0.0, 1.0, counts[0]):
        for focus in np.linspace(0.0, 1.0, counts[1]):
            focal_mm, focus_m = (float(v) for v in profile.from_encoders(zoom, focus))
            focus_m = infinity_m if math.isinf(focus_m) else focus_m
            samples.append((float(zoom), float(focus), focal_mm, focus_m, camera_at(profile, focal_mm, focus_m)))
    return samples


def _export_table(profile: LensProfile, path: Path, name: str) -> Any:
    """The lens table (:mod:`camcal.io.lens_table`) on a grid of OpenTrackIO encoders over the calibrated range."""
    from camcal.io.conversion import ExportResult
    from camcal.io.lens_table import write_lens_table

    samples = _encoder_grid(profile)
    write_lens_table(path, samples, name=name, image_size=profile.image_size, focal_range=profile.focal_range,
                     focus_range=profile.focus_range)
    counts = (len({s[0] for s in samples}), len({s[1] for s in samples}))
    worst = max(camera.quality.worst_projection_sigma_px for *_, camera in samples)
    return ExportResult((path,), (), (f"{len(samples)} samples ({counts[0]} zoom x {counts[1]} focus encoder "
                                      f"values); worst projection sigma {worst:.3g} px",))


def _export_tde(profile: LensProfile, path: Path, name: str, sensor_width_mm: float | None) -> Any:
    """3DE dynamic distortion: the encoder grid as a rig with a lens per frame, written by :mod:`camcal.io.tde`."""
    from dataclasses import replace

    from camcal.io.interchange import export_rig
    from camcal.model.rig import Frame, Lens, Rig, make_provenance

    samples = _encoder_grid(profile, TDE_INFINITY_M)
    cameras = [replace(camera, name=name, sensor_width_mm=sensor_width_mm) for *_, camera in samples]
    frames = tuple(Frame(index, np.eye(3), np.zeros(3), lenses={name: Lens(camera.K, camera.distortion, focal, focus)})
                   for index, ((_, _, focal, focus, _), camera) in enumerate(zip(samples, cameras)))
    rig = Rig((cameras[0],), units="unknown", frames=frames, provenance=make_provenance("rig export"))
    result = export_rig(rig, "3de", path)
    notes = list(result.notes)
    if math.isinf(profile.focus_range[1]):
        notes.append(f"the focus at infinity is keyed at {TDE_INFINITY_M / 1000:g} km (3DE keys focus distances)")
    return replace(result, notes=(f"{len(samples)} lens states (frame i: the i-th, zoom over focus encoders)",
                                  *notes))
