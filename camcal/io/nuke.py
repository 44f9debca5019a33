"""Nuke scripts (``.nk``): a Camera3 node per camera, its lens as LensDistortion and LDPK nodes and an STMap chain.

Camera3 (classic 3D system; looks down -Z with +Y up, Nuke's world +Y up).
Nuke's world is camcal's turned half a turn about x (``X_nuke = D X``,
``D = diag(1, -1, -1)``, as in :mod:`camcal.io.usd`); the camera's
local-to-world rotation is ``D R^T D`` written as ``rotate`` with
``rot_order XYZ`` (x first: ``M = R_z R_y R_x``, degrees) and its position
``translate = D c``. Intrinsics, with the film back ``haperture`` the sensor
width in mm (36 without one)::

    focal         = fx haperture / W
    vaperture     = haperture H / W
    win_translate = ((cx - W/2 + 0.5) 2 / W,  (H/2 - 0.5 - cy) 2 / (W pixel_aspect))

Nuke's camera projection has one focal scale for x and y, the format's
pixel aspect does the rest (``fy = pixel_aspect fx``: the Root ``format``,
written with the first camera's ``fy / fx``, as a 2x anamorphic plate's
format has pixel aspect 2), and no skew: a camera with skew, or whose
``fy / fx`` differs from the Root format's pixel aspect, is written with
``fx``, that pixel aspect and no skew, and the max pixel residual of the
(undistorted) projection is reported. Reading applies the Root format's
pixel aspect to every Camera3.
A moving rig animates ``translate`` and ``rotate`` with one key per frame
(``{curve x<frame> value ...}``). The image size and the camcal lens are
kept on the node as user knobs (``image_width``, ``image_height``,
``lens_model``, ``lens_params``, ``lens_center``) so that the import
reads them back.

Lens, three ways, for every camera:

- the ST-maps (:mod:`camcal.io.stmap`), exact for every camcal lens, written
  beside the script, ``<script>_stmaps/<camera>_undistort.exr`` and
  ``..._redistort.exr``, in the chain ``Read (plate) -> STMap (undistort
  map) -> ... -> STMap (redistort map)``, each STMap taking its source on
  input 0 and the map on input 1 (cameras with a lens);
- a ``LensDistortion2`` node (plain Nuke, no plugin) with the 3DEqualizer
  preset of the lens' 3DE model (``distortionModelPreset
  "3DEqualizer/3DE4 Radial - Standard, Degree 4"`` ...), ``normalisationType
  Diagonal``, ``output Undistort``, ``focal`` and ``sensorSize`` in mm (the
  Camera3's), the lens-centre offset over the film back's half-diagonal as
  ``centre``, the image size and pixel aspect as ``distortionScalingFormat``
  and each 3DE parameter on the knob 3DEqualizer's own Nuke export puts it
  (``Distortion - Degree 2`` -> ``distortionNumerator0``, ``U - Degree 2`` ->
  ``distortionNumeratorT0``, ``Cx02 - Degree 2`` -> ``distortionNumeratorX00``,
  ``Lens Rotation`` -> ``anamorphicTwist``, ``Squeeze-X / -Y`` ->
  ``anamorphicScale``, ``Phi / B - Cylindric`` -> ``beamSplitterDirection /
  Bending``, ...);
- the LDPK node of the same model (``LD_3DE4_Anamorphic_Standard_Degree_4``
  ...: 3DE's names with ``+,:; _-`` runs as one underscore) with LDPK's
  built-in ``tde4_*`` knobs in cm (focal length, film back, lens-centre
  offset, pixel aspect) and the model parameters by their 3DE names.

A lens that is one of the four 3DE models goes into the lens nodes exactly;
any other is refitted to the nearest 3DE model
(:func:`camcal.io.conversion.refit_camera`, residual max / RMS over the
image and a 1.25 overscan border printed). The film back is ``haperture``
wide for all three, so the Camera3's focal length and film back are the
lens nodes'. (A refit to 3DE's fisheye, whose equisolid image takes the
focal length, fits the focal length too: its lens nodes carry their own.)
Reading takes each Camera3's lens from its camcal knobs; a Camera3 without
them (Nuke's own) from the LDPK node ``<node>_ldpk`` or LensDistortion node
``<node>_lens`` (the only one, with one camera); a script with lens nodes and
no Camera3 gives one camera per lens node (LDPK nodes first), at the origin.
Image sizes come from the camcal knobs, the LensDistortion node's format,
the Root's ``format`` or the ``image_size`` given to :func:`load`.

Per-frame lenses (a zoom, a rack focus: :attr:`camcal.model.rig.Frame.lenses`):
a camera whose lens changes over the rig's frames gets one key per frame on
the Camera3's ``focal``, ``haperture`` (the sensor width: the same on every
frame) and ``win_translate``, on every lens knob of its LensDistortion and LDPK nodes (each
frame's lens refitted on its own where the family does not hold it; the
worst frame's residual printed; :mod:`camcal.io.nuke_lens`) and a camcal
knob ``lens_keys`` (``x<frame> k=v ... [center=x,y] [focal_mm=v]
[focus_m=v]`` per frame, the lens exactly); its ST-maps are a pair per
frame, ``<camera>_undistort.%04d.exr`` / ``<camera>_redistort.%04d.exr``
read as sequences (``first`` / ``last``) by the chain's Read nodes
(:func:`camcal.io.stmap.write_stmap_frames`). Reading gives the frames a
lens where the keyed focal length, film back offset or lens (``lens_keys``,
or the paired lens node's keys) differ from the first frame's.

No Nuke was available to check these files: the conventions above are the
ones Foundry documents for Camera3, STMap and LensDistortion (knob names)
and 3DEqualizer's Nuke export uses (the 3DE parameters' knobs); the tests
evaluate the written knobs with the LDPK models' documented formulas,
independently of camcal's model code.

References
----------
Foundry, Nuke reference guide: Camera, STMap, LensDistortion
(learn.foundry.com/nuke/content/reference_guide/transform_nodes/lensdistortion.html).
Science-D-Visions, 3DEqualizer4 "Export Nuke LD_3DE4 Lens Distortion Node"
and "Export Nuke LensDistortion Node" scripts; Lens Distortion Plugin Kit 2.0.
"""

from __future__ import annotations

import re
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from camcal.base.errors import CamcalError
from camcal.model.distortion import Distortion
from camcal.base.atomic import atomic_write_text
from camcal.base.limits import FILE_BYTES, check_file_size
from camcal.io.conversion import (
    FORMAT_FAMILIES,
    ExportResult,
    ImportResult,
    LensConversion,
    max_pixel_residual,
    nearest_family,
    refit_camera,
    select_cameras,
)
from camcal.io.nuke_knobs import animated_knob, blocks, keyed_knob, knob_text, number, parse_number, value_at
from camcal.io.nuke_lens import format_knob, ldpk_node_class, lens_nodes, lens_nodes_of, node_lenses
from camcal.model.rig import Camera, Frame, Lens, Rig
from camcal.model.tde4 import LDPK_MODEL_NAMES

__all__ = ["DEFAULT_HAPERTURE_MM", "ldpk_node_class", "nuke_intrinsics", "export", "load"]

#: Film back width of cameras without ``sensor_width_mm``.
DEFAULT_HAPERTURE_MM = 36.0

_D = np.diag([1.0, -1.0, -1.0])


def nuke_intrinsics(camera: Camera) -> dict[str, float | tuple[float, float]]:
    """``focal``, ``haperture``, ``vaperture`` and ``win_translate`` of a camera (see the module docstring), its
    ``fy / fx`` the format's pixel aspect."""
    width, height = camera.image_size
    K = camera.K
    pixel_aspect = K[1, 1] / K[0, 0]
    haperture = camera.sensor_width_mm or DEFAULT_HAPERTURE_MM
    return {
        "focal": K[0, 0] * haperture / width,
        "haperture": haperture,
        "vaperture": haperture * height / width,
        "win_translate": ((K[0, 2] - width / 2 + 0.5) * 2 / width,
                          (height / 2 - 0.5 - K[1, 2]) * 2 / (width * pixel_aspect)),
    }


def _K_from_nuke(focal: float, haperture: float, win_translate, image_size: tuple[int, int],
                 pixel_aspect: float = 1.0) -> np.ndarray:
    width, height = image_size
    f = focal * width / haperture
    cx = win_translate[0] * width / 2 + width / 2 - 0.5
    cy = height / 2 - 0.5 - win_translate[1] * width * pixel_aspect / 2
    return np.array([[f, 0.0, cx], [0.0, f * pixel_aspect, cy], [0.0, 0.0, 1.0]])


def _transform(R: np.ndarray, c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Nuke ``translate`` and ``rotate`` (degrees, rot_order XYZ) of a camcal pose."""
    return _D @ c, Rotation.from_matrix(_D @ R.T @ _D).as_euler("xyz", degrees=True)


def _node_name(name: str) -> str:
    return re.sub(r"\W", "_", name) if re.match(r"[A-Za-z_]", name) else "cam_" + re.sub(r"\W", "_", name)


def _square(camera: Camera, pixel_aspect: float) -> Camera:
    """The camera as Camera3 in a format of ``pixel_aspect`` holds it: one focal scale (``fx``, ``fy = pixel_aspect
    fx``), no skew; the lens kept for the ST-maps."""
    K = camera.K.copy()
    K[0, 1], K[1, 1] = 0.0, K[0, 0] * pixel_aspect
    return Camera(camera.name, camera.image_size, K, camera.distortion, camera.R, camera.c, camera.sensor_width_mm)


def _lens_text(distortion: Distortion) -> tuple[str, str]:
    """The camcal knobs ``lens_params`` and ``lens_center`` of a lens."""
    params = " ".join(f"{k}={number(v)}" for k, v in distortion.params.items())
    centre = "" if distortion.center is None else f"{number(distortion.center[0])} {number(distortion.center[1])}"
    return params, centre


def _lens_keys(rig: Rig, name: str) -> str:
    """The camcal knob ``lens_keys``: ``x<frame> k=v ... [center=x,y] [focal_mm=v] [focus_m=v]`` per frame."""
    tokens = []
    for frame in rig.frames:
        lens = rig.camera_at_frame(name, frame.index).distortion
        params, centre = _lens_text(lens)
        state = frame.lenses.get(name)
        tokens += [f"x{frame.index}", params] + ([f"center={centre.replace(' ', ',')}"] if centre else [])
        for key in ("focal_mm", "focus_m"):
            value = None if state is None else getattr(state, key)
            if value is not None:
                tokens.append(f"{key}={number(value)}")
    return " ".join(token for token in tokens if token)


def export(rig: Rig, out: Path, *, cameras: Sequence[str] | None = None, rig_path: Path | None = None) -> ExportResult:
    """Write the script (and the ST-maps of cameras with a lens) (see the module docstring)."""
    from camcal.io.stmap import stmap_frame_name, write_stmap_frames, write_stmaps

    if out.suffix.lower() != ".nk":
        raise CamcalError(f"a Nuke script must end in .nk, got {out.name!r}")
    chosen = select_cameras(rig, cameras)
    frames = [frame.index for frame in rig.frames] or None
    names = [_node_name(camera.name) for camera in chosen]
    if len(set(names)) != len(names):
        raise CamcalError(f"camera names {', '.join(c.name for c in chosen)} give repeated Nuke node names")
    lines = ["#! nuke script written by camcal", "version 15.1 v1", "Root {", " inputs 0",
             f" first_frame {frames[0] if frames else 1}", f" last_frame {frames[-1] if frames else 1}",
             f" format {format_knob(chosen[0])}", "}"]
    conversions, written, mapped = [], [], 0
    pixel_aspect = chosen[0].K[1, 1] / chosen[0].K[0, 0]  # the Root format's (format_knob)
    map_dir = out.with_name(out.stem + "_stmaps")
    for index, (camera, node) in enumerate(zip(chosen, names)):
        # per-frame lenses: every lens knob keyed on every frame, each frame's lens refitted on its own
        lens_frames = frames if rig.lens_frames(camera.name) else None
        states = [rig.camera_at_frame(camera.name, f) for f in lens_frames] if lens_frames else [camera]
        squared = [_square(state, pixel_aspect) for state in states]
        exact = all(np.array_equal(a.K, b.K) for a, b in zip(squared, states))
        source = f"{camera.distortion.model}{' with skew' if camera.K[0, 1] else ''}" + (
            "" if camera.K[1, 1] == camera.K[0, 0] * pixel_aspect else ", fy / fx not the Root format's pixel aspect")
        family = nearest_family(camera.distortion, FORMAT_FAMILIES["nuke"])
        refits = [refit_camera(state, family) for state in states]
        worst = max((refit for _, refit in refits), key=lambda refit: refit.max_px)
        keyed = f", keyed on {len(states)} frames (the worst frame's figures)" if lens_frames else ""
        conversions.append(LensConversion(
            camera.name, source, f"Nuke Camera3 (+ ST-maps for the lens), lens nodes {LDPK_MODEL_NAMES[family]}{keyed}",
            exact, 0.0 if exact else max(max_pixel_residual(a, b, lens=False) for a, b in zip(states, squared)),
            "one focal scale and the Root format's pixel aspect, no skew", worst))
        if frames:
            posed = [rig.camera_at_frame(camera.name, f) for f in frames]
            poses = [_transform(p.R, p.c) for p in posed]
            translate, rotate = np.array([p[0] for p in poses]), np.array([p[1] for p in poses])
        else:
            translate, rotate = _transform(camera.R, camera.c)
        intrinsics = [nuke_intrinsics(state) for state in squared]
        first = intrinsics[0]
        lines += lens_nodes([lens for lens, _ in refits], lens_frames, node, first["haperture"], index)
        width, height = camera.image_size
        params, centre = _lens_text(camera.distortion)
        lines += [
            "Camera3 {", " inputs 0", " rot_order XYZ",
            f" translate {animated_knob(translate, frames)}", f" rotate {animated_knob(rotate, frames)}",
            f" focal {animated_knob([i['focal'] for i in intrinsics] if lens_frames else first['focal'], lens_frames)}",
            " haperture " + animated_knob([i["haperture"] for i in intrinsics] if lens_frames else first["haperture"],
                                          lens_frames),
            f" vaperture {number(first['vaperture'])}",
            " win_translate " + animated_knob([i["win_translate"] for i in intrinsics] if lens_frames
                                              else first["win_translate"], lens_frames),
            f" name {node}", f" xpos {index * 150}", " ypos 0",
            " addUserKnob {20 camcal l camcal}",
            " addUserKnob {1 camera_name}", f' camera_name "{camera.name}"',
            " addUserKnob {3 image_width}", f" image_width {width}",
            " addUserKnob {3 image_height}", f" image_height {height}",
            " addUserKnob {1 lens_model}", f' lens_model "{camera.distortion.model}"',
            " addUserKnob {1 lens_params}", f' lens_params "{params}"',
            " addUserKnob {1 lens_center}", f' lens_center "{centre}"',
            *([" addUserKnob {1 lens_keys}", f' lens_keys "{_lens_keys(rig, camera.name)}"']
              if lens_frames else []),
            "}",
        ]
        if not all(state.distortion.is_identity for state in states):
            mapped += 1
            if lens_frames:
                undistort_maps, redistort_maps, _ = write_stmap_frames(rig, camera.name, map_dir)
                written += [*undistort_maps, *redistort_maps]
                undistort = map_dir.resolve() / stmap_frame_name(camera.name, "undistort", 0).replace(".0000.", ".%04d.")
                redistort = map_dir.resolve() / stmap_frame_name(camera.name, "redistort", 0).replace(".0000.", ".%04d.")
                sequence = [f" first {lens_frames[0]}", f" last {lens_frames[-1]}"]
            else:
                undistort, redistort, _ = write_stmaps(rig, camera.name, map_dir)
                written += [undistort, redistort]
                sequence = []
            lines += [
                "Read {", " inputs 0", f' file "{node}_plate.####.exr"', f" name {node}_plate",
                f" xpos {index * 150}", " ypos 100", "}",
                "Read {", " inputs 0", f' file "{undistort.resolve()}"', *sequence, " raw true",
                f" name {node}_undistort_map", f" xpos {index * 150 + 100}", " ypos 100", "}",
                "STMap {", " inputs 2", " channels rgba", " uv rgb", f" name {node}_undistort",
                f" xpos {index * 150}", " ypos 200", "}",
                "Read {", " inputs 0", f' file "{redistort.resolve()}"', *sequence, " raw true",
                f" name {node}_redistort_map", f" xpos {index * 150 + 100}", " ypos 300", "}",
                "STMap {", " inputs 2", " channels rgba", " uv rgb", f" name {node}_redistort",
                f" xpos {index * 150}", " ypos 400", "}",
            ]
    notes = []
    if any(abs(c.K[1, 1] / c.K[0, 0] - 1.0) > 1e-9 for c in chosen):
        notes.append("non-square pixels: the pixel aspect is in the Root format and the LensDistortion node's "
                     "distortionScalingFormat (not checked in Nuke); the LDPK node (tde4_pixel_aspect) and the ST-maps "
                     "hold the lens")
    if rig.points is not None:
        notes.append("sparse points are not written to Nuke (export USD for a point cloud)")
    if written:
        notes.append(f"ST-maps of {mapped} camera(s) written to {map_dir} (a pair per frame where the lens changes); "
                     "the plate Read nodes name a placeholder file to replace")
    atomic_write_text(out, "\n".join(lines) + "\n")
    return ExportResult((out, *written), tuple(conversions), tuple(notes))


# -- reading: the Camera3 nodes (camcal's and Nuke's own, static or keyed) ----------------


def _root_format(text: str) -> tuple[tuple[int, int] | None, float]:
    """The image size (None without one) and pixel aspect (1 without one) of the Root's format knob."""
    root = blocks(text, "Root")
    fmt = (knob_text(root[0][1], "format") or "").strip('"').split() if root else []
    size = ((int(parse_number(fmt[0], "Root format")), int(parse_number(fmt[1], "Root format")))
            if len(fmt) >= 2 else None)
    pixel_aspect = parse_number(fmt[6], "Root format pixel aspect") if len(fmt) >= 7 else 1.0
    if not pixel_aspect > 0.0:
        raise CamcalError(f"Root format: pixel aspect {fmt[6]} is not positive")
    return size, pixel_aspect


def _K_at(focal, haperture, win, frame: int | None, size: tuple[int, int], where: str,
          pixel_aspect: float) -> np.ndarray:
    """``K`` of a Camera3's (keyed or constant) ``focal``, ``haperture`` and ``win_translate`` at ``frame``, in a
    format of ``pixel_aspect``."""
    return _K_from_nuke(float(value_at(focal, frame, f"{where} focal")[0]),
                        float(value_at(haperture, frame, f"{where} haperture")[0]),
                        value_at(win, frame, f"{where} win_translate"), size, pixel_aspect)


def _parse_lens(tokens: Sequence[str], where: str) -> tuple[dict[str, float], tuple[float, ...] | None, dict[str, float]]:
    """``k=v`` tokens of ``lens_params`` / ``lens_keys``: the parameters, the centre, the lens state."""
    params, centre, state = {}, None, {}
    for item in tokens:
        key, _, value = item.partition("=")
        if key == "center":
            centre = tuple(parse_number(v, f"{where} center") for v in value.split(","))
        elif key in ("focal_mm", "focus_m"):
            state[key] = parse_number(value, f"{where} {key}")
        else:
            params[key] = parse_number(value, where)
    return params, centre, state


def _keyed_lenses(text: str, model: str, where: str) -> dict[int, tuple[Distortion, dict[str, float]]]:
    """The camcal knob ``lens_keys``: frame -> (the lens, its state)."""
    out, frame, tokens = {}, None, []
    for token in [*text.strip('"').split(), "x"]:
        if token.startswith("x") and "=" not in token:
            if frame is not None:
                params, centre, state = _parse_lens(tokens, f"{where} lens_keys")
                out[frame] = (Distortion(model, params, centre), state)
            frame, tokens = (int(parse_number(token[1:], f"{where} lens_keys")) if token != "x" else None), []
        elif frame is None:
            raise CamcalError(f"{where} lens_keys: {token!r} before the first frame (x<frame>)")
        else:
            tokens.append(token)
    return out


def load(path: Path, *, image_size: tuple[int, int] | None = None) -> ImportResult:
    """Read the Camera3 nodes of a script and their lens nodes (see the module docstring).

    ``image_size`` stands in for a Root format where the script has none
    (an LDPK node 3DEqualizer exported on its own).
    """
    check_file_size(path, FILE_BYTES, "Nuke script")
    text = path.read_text(errors="replace")
    bodies = [body for _, body in blocks(text, r"Camera[23]?")]
    lens_node_bodies = lens_nodes_of(text)
    root_size, pixel_aspect = _root_format(text)
    root_size = root_size or image_size
    if not bodies:
        return _lens_only(lens_node_bodies, root_size)
    cameras, conversions, animated, lenses = [], [], [], []
    for body in bodies:
        node = knob_text(body, "name") or f"Camera{len(cameras) + 1}"
        where = f"camera node {node}"
        width, height = knob_text(body, "image_width"), knob_text(body, "image_height")
        if (width is None or height is None) and root_size is None:
            raise CamcalError(f"{where} has no image_width / image_height knobs (Nuke cameras hold no image size)")
        size = root_size if width is None or height is None else (int(parse_number(width, where)),
                                                                 int(parse_number(height, where)))
        focal = keyed_knob(knob_text(body, "focal"), 1, f"{where} focal", 50.0)
        haperture = keyed_knob(knob_text(body, "haperture"), 1, f"{where} haperture", 24.576)
        win = keyed_knob(knob_text(body, "win_translate"), 2, f"{where} win_translate", (0.0, 0.0))
        model = (knob_text(body, "lens_model") or '"none"').strip('"')
        params, centre, _ = _parse_lens((knob_text(body, "lens_params") or '""').strip('"').split(),
                                        f"{where} lens_params")
        centre_text = (knob_text(body, "lens_center") or '""').strip('"').split()
        centre = tuple(parse_number(v, f"{where} lens_center") for v in centre_text) or None
        keys_text = knob_text(body, "lens_keys")
        order = (knob_text(body, "rot_order") or "ZXY").lower()
        if sorted(order) != ["x", "y", "z"]:
            raise CamcalError(f"{where}: unknown rot_order {order!r}")
        translate = keyed_knob(knob_text(body, "translate"), 3, f"{where} translate", (0.0, 0.0, 0.0))
        rotate = keyed_knob(knob_text(body, "rotate"), 3, f"{where} rotate", (0.0, 0.0, 0.0))
        name = (knob_text(body, "camera_name") or node).strip('"')
        source = "Nuke Camera3"
        paired = [n for n in (f"{node}_ldpk", f"{node}_lens") if n in lens_node_bodies] or (
            list(lens_node_bodies)[:1] if len(bodies) == 1 else [])
        node_lens: dict = {}
        if knob_text(body, "lens_model") is None and paired:
            cls, lens_body = lens_node_bodies[paired[0]]
            node_lens, _ = node_lenses(cls, lens_body, size, f"lens node {paired[0]}")
            lens = next(iter(node_lens.values()))[1]
            model, params, centre, source = lens.model, dict(lens.params), None, f"Nuke {cls}"
        try:
            distortion = Distortion(model, params, centre)
            keyed_lenses = _keyed_lenses(keys_text, model, where) if keys_text else {}
            frames = sorted({f for knob in (focal, haperture, win) if isinstance(knob, dict) for f in knob}
                            | set(keyed_lenses) | {f for f in node_lens if f is not None})
            per_frame = {}
            for f in frames:  # the lens from camcal's knob, else the lens node's keys, else the camera's lens
                lens, state = keyed_lenses.get(f, (node_lens[f][1] if f in node_lens else distortion, {}))
                per_frame[f] = (_K_at(focal, haperture, win, f, size, where, pixel_aspect), lens, state)
            lenses.append(per_frame or None)
            K, distortion = per_frame[frames[0]][:2] if per_frame else (
                _K_at(focal, haperture, win, None, size, where, pixel_aspect), distortion)
            if isinstance(translate, dict) or isinstance(rotate, dict):
                keys = sorted(translate if isinstance(translate, dict) else rotate)
                poses = {f: _pose_order(value_at(translate, f, f"{where} translate"),
                                        value_at(rotate, f, f"{where} rotate"), order) for f in keys}
                animated.append(poses)
                R, c = poses[keys[0]]
            else:
                R, c = _pose_order(translate, rotate, order)
                animated.append(None)
            cameras.append(Camera(name, size, K, distortion, R, c))
        except CamcalError as error:
            raise CamcalError(f"{where}: {error}") from None
        conversions.append(LensConversion(name, source, distortion.model, True))
    if all(a is None for a in animated) and all(lens is None for lens in lenses):
        return ImportResult(Rig(tuple(cameras), units="unknown"), tuple(conversions))
    notes = ["frames from the keyed cameras"] + (
        [f"per-frame lenses of {sum(lens is not None for lens in lenses)} camera(s) from their keyed focal length, "
         "film back offset and lens"] if any(lens is not None for lens in lenses) else [])
    return ImportResult(_moving(cameras, animated, lenses), tuple(conversions), tuple(notes))


def _lens_only(lens_node_bodies: dict[str, tuple[str, str]], root_size: tuple[int, int] | None) -> ImportResult:
    """A rig of the lens nodes alone (a script with no camera): one camera per lens, at the origin."""
    if not lens_node_bodies:
        raise CamcalError("no Camera3 node and no LensDistortion (3DEqualizer preset) or LDPK node in the script")
    chosen = {n: v for n, v in lens_node_bodies.items() if v[0].startswith("LD")} or lens_node_bodies
    cameras, conversions, lenses = [], [], []
    for name, (cls, body) in chosen.items():
        keyed, size = node_lenses(cls, body, root_size, f"lens node {name}")
        K, lens = next(iter(keyed.values()))
        try:
            cameras.append(Camera(name, size, K, lens, np.eye(3), np.zeros(3)))
        except CamcalError as error:
            raise CamcalError(f"lens node {name}: {error}") from None
        lenses.append({f: (K_f, lens_f, {}) for f, (K_f, lens_f) in keyed.items()} if None not in keyed else None)
        conversions.append(LensConversion(name, f"Nuke {cls}", lens.model, True))
    notes = ("no Camera3 node: one camera per lens node, at the origin",)
    if all(lens is None for lens in lenses):
        return ImportResult(Rig(tuple(cameras), units="unknown"), tuple(conversions), notes)
    return ImportResult(_moving(cameras, [None] * len(cameras), lenses), tuple(conversions), notes)


def _pose_order(translate: np.ndarray, rotate: np.ndarray, order: str) -> tuple[np.ndarray, np.ndarray]:
    M = Rotation.from_euler(order, rotate, degrees=True).as_matrix()
    return _D @ M.T @ _D, _D @ translate


def _moving(cameras: list[Camera], animated: list, lenses: list) -> Rig:
    """A moving rig: the frames of the keyed poses (the first camera's) or, with none, of the keyed lenses.

    Every camera keeps its pose relative to the first camera's at the first
    frame; a camera whose lens is keyed gets its lens at each frame
    (:attr:`camcal.model.rig.Frame.lenses`) where it differs from its first
    frame's, which is the camera's own.
    """
    reference = animated[0]
    if any(a is not None for a in animated) and (
            reference is None or any(a is not None and sorted(a) != sorted(reference) for a in animated)):
        raise CamcalError("the cameras are keyed on different frames")
    indices = sorted(reference) if reference is not None else sorted({f for keyed in lenses if keyed for f in keyed})
    for camera, keyed in zip(cameras, lenses):
        if keyed is not None and sorted(keyed) != indices:
            raise CamcalError(f"camera {camera.name!r}: its lens is keyed on {len(keyed)} frames, the shot has "
                              f"{len(indices)} (key the lens and the camera on the same frames)")
    first = indices[0]
    poses = reference or {index: (np.eye(3), np.zeros(3)) for index in indices}
    R0, c0 = poses[first]
    rig_cameras, frame_lenses = [], {index: {} for index in indices}
    for camera, posed, keyed in zip(cameras, animated, lenses):
        R, c = posed[first] if posed is not None else (camera.R, camera.c)
        rig_cameras.append(Camera(camera.name, camera.image_size, camera.K, camera.distortion, R @ R0.T, R0 @ (c - c0)))
        for index, (K, lens, state) in (keyed or {}).items():
            if not (np.array_equal(K, camera.K) and lens == camera.distortion and not state):
                frame_lenses[index][camera.name] = Lens(K, lens, state.get("focal_mm"), state.get("focus_m"))
    frames = tuple(Frame(index, *poses[index], lenses=frame_lenses[index]) for index in indices)
    return Rig(tuple(rig_cameras), units="unknown", frames=frames)
