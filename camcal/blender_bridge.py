"""Running the Blender add-on's importer from camcal, without importing bpy here.

``camcal blender import RIG --blend OUT.blend`` (or ``--into SCENE.blend``,
an existing file; a second import of the same rig replaces the first in
place) runs the add-on's ``import_rig`` in a subprocess of the same Python interpreter, which has
the ``bpy`` module (the ``blender`` extra): camcal itself never imports bpy,
and Blender's global state stays out of the calling process.

The add-on lives in ``addon/`` beside the ``camcal`` package (a source
checkout or editable install); ``CAMCAL_ADDON_DIR`` overrides the location.

Blender's tracking camera holds camcal's ``polynomial``, ``opencv`` (``k1,
k2, p1, p2, k3``) and round ``division`` lenses exactly (the add-on's
``tracking.blender_lens``); before the import, every other lens but the
fisheyes (Cycles' fisheye camera takes those) is replaced in the MovieClip
by its nearest lens of that kind (:func:`camcal.io.conversion.refit_camera`,
the residual reported), and its distortion compositor re-distorts with
camcal's exact map through a Map UV node instead
(:func:`write_blender_uv_maps`): the ST-map path.
"""

from __future__ import annotations

import importlib
import importlib.util
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from camcal import resources
from camcal.base.errors import CamcalError
from camcal.base.extras import check_installed
from camcal.io.conversion import LensConversion, max_pixel_residual, refit_camera
from camcal.model.distortion import Distortion
from camcal.model.rig import Lens, Rig

__all__ = [
    "ADDON_PACKAGE",
    "addon_dir",
    "load_addon",
    "blender_tracking_rig",
    "write_blender_uv_maps",
    "import_rig_to_blend",
    "extension_tool",
    "build_extension",
]

ADDON_PACKAGE = "camcal_rig"

# The script the subprocess runs: arguments come as one JSON string.
_SCRIPT = r"""
import json, os, sys
args = json.loads(sys.argv[1])
try:
    import bpy
except ImportError as error:
    print(f"the bpy module is not installed ({error}); install camcal[blender]", file=sys.stderr)
    sys.exit(3)
from camcal.blender_bridge import load_addon
addon = load_addon()
from camcal_rig.rigfile import RigFileError
from camcal_rig.reimport import import_in_place
if args["into"]:
    try:
        bpy.ops.wm.open_mainfile(filepath=args["into"], load_ui=False)
    except RuntimeError as error:
        print(f"cannot open {args['into']}: {str(error).strip().splitlines()[-1]}", file=sys.stderr)
        sys.exit(2)
else:
    bpy.ops.wm.read_factory_settings(use_empty=True)
scene = bpy.context.scene
try:
    result, replaced = import_in_place(scene, args["rig"], source=args["source"], replace=args["replace"],
                                       **args["options"])
except (RigFileError, OSError, ValueError) as error:
    print(str(error), file=sys.stderr)
    sys.exit(2)
out = args["blend"]
tmp = os.path.join(os.path.dirname(out), "." + os.path.basename(out) + ".tmp.blend")
try:
    bpy.ops.wm.save_as_mainfile(filepath=tmp, check_existing=False, copy=True)
    os.replace(tmp, out)
finally:
    if os.path.exists(tmp):
        os.unlink(tmp)
summary = {
    "rig": result.rig.name,
    "collection": result.collection.name,
    "replaced": replaced,
    "scene": scene.name,
    "cameras": {name: obj.name for name, obj in result.cameras.items()},
    "stereo_mode": result.stereo_mode,
    "clips": sorted(result.clips),
    "distorted_scenes": {k: v.name for k, v in result.distorted_scenes.items()},
    "points": result.points.name if result.points is not None else None,
    "warnings": result.warnings,
}
print("CAMCAL_RESULT " + json.dumps(summary))
"""

def addon_dir() -> Path:
    """The folder of the Blender add-on (:func:`camcal.resources.addon_dir`; ``CAMCAL_ADDON_DIR`` overrides it)."""
    override = os.environ.get("CAMCAL_ADDON_DIR")
    folder = Path(override) if override else resources.addon_dir()
    if not (folder / "blender_manifest.toml").is_file():
        raise CamcalError(
            f"the Blender add-on was not found at {folder} (set CAMCAL_ADDON_DIR to its folder)"
        )
    return folder


def load_addon(name: str = ADDON_PACKAGE):
    """Import the add-on as package ``name`` (as Blender would, relative imports intact).

    Only the pure modules load without bpy; ``import_rig`` needs it.
    """
    if name in sys.modules:
        return sys.modules[name]
    folder = addon_dir()
    spec = importlib.util.spec_from_file_location(
        name, folder / "__init__.py", submodule_search_locations=[str(folder)]
    )
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module
    try:
        spec.loader.exec_module(module)
    except BaseException:
        del sys.modules[name]
        raise
    return module


def _tracking_holds(distortion: Distortion) -> bool:
    """Whether the add-on takes ``distortion`` as it is: a tracking-camera model holds it, or it is a fisheye."""
    p = distortion.params
    if distortion.model == "opencv":
        return not any(p.get(name, 0.0) for name in ("k4", "k5", "k6", "s1", "s2", "s3", "s4"))
    if distortion.model == "division":
        return abs(p.get("aspect", 1.0) - 1.0) <= 1e-9  # the add-on's tracking.ROUND_ASPECT
    return distortion.model in ("none", "polynomial") or distortion.is_fisheye


#: The lens fitted where Blender's tracking camera does not hold one (see :func:`blender_tracking_rig`).
_NEAREST = {"opencv": "opencv", "polynomial": "polynomial", "division": "division", "none": "polynomial",
            "kannala-brandt": "kannala-brandt", "kannala-brandt-thin-prism": "kannala-brandt",
            "3de-classic": "opencv", "3de4-radial-deg4": "opencv", "3de4-anamorphic-deg4": "opencv",
            "3de4-fisheye-deg8": "kannala-brandt"}
#: What a refit to each family holds, for Blender: BROWN has no rational or thin-prism terms, NUKE is round.
_HELD = {"opencv": dict.fromkeys(("k4", "k5", "k6", "s1", "s2", "s3", "s4"), 0.0), "division": {"aspect": 1.0}}
_BLENDER_NAMES = {"opencv": "Blender BROWN", "polynomial": "Blender POLYNOMIAL", "division": "Blender NUKE",
                  "kannala-brandt": "Cycles fisheye"}


def blender_tracking_rig(rig: Rig, overscan: float = 1.1) -> tuple[Rig, tuple[LensConversion, ...]]:
    """The rig with each lens Blender cannot hold replaced by the nearest one it can, and what that cost.

    ``opencv`` with rational or thin-prism terms and 3DE's lenses become
    the nearest ``opencv`` lens of ``k1, k2, p1, p2, k3`` (Blender's BROWN;
    3DE4 Radial Fisheye the nearest ``kannala-brandt``, for Cycles' fisheye
    camera), a ``division`` lens with an aspect the nearest round one
    (NUKE), a lens with a correction field the nearest of its own kind
    without it (:func:`camcal.io.conversion.refit_camera`). Each replaced
    camera's :class:`~camcal.io.conversion.LensConversion` gives the largest
    pixel distance between the two lenses over the frame and the refit's
    figures (inside the image and over the border of ``overscan``, the
    factor the add-on's distortion compositor renders with, which the fit
    covers as well). A camera whose lens changes over the frames has each
    frame's lens refitted the same way; its conversion gives the worst
    frame's figures.
    """
    out, conversions = rig, []
    for camera in rig.cameras:
        distortion = camera.distortion
        if _tracking_holds(distortion) and not distortion.has_correction:
            continue
        fit = _NEAREST[distortion.model]
        converted, refit = refit_camera(camera, fit, overscan=overscan, fixed=_HELD.get(fit))
        worst, lenses = (max_pixel_residual(camera, converted), refit), {}
        for frame in rig.frames:  # a zoom: each frame's lens refitted the same way
            state = frame.lenses.get(camera.name)
            if state is not None:
                at = rig.camera_at_frame(camera.name, frame.index)
                at_converted, at_refit = refit_camera(at, fit, overscan=overscan, fixed=_HELD.get(fit))
                lenses[frame.index] = Lens(at_converted.K, at_converted.distortion, state.focal_mm, state.focus_m)
                worst = max(worst, (max_pixel_residual(at, at_converted), at_refit), key=lambda pair: pair[0])
        out = out.with_camera(converted, lenses)
        conversions.append(LensConversion(camera.name, distortion.model, _BLENDER_NAMES[fit], False, worst[0],
                                          refit=worst[1]))
    return out, tuple(conversions)


def write_blender_uv_maps(rig: Rig, names: list[str], folder: str | os.PathLike, overscan: float) -> dict[str, str]:
    """camcal's exact redistort maps of cameras, as the UV of Blender's Map UV node on the add-on's overscan frame.

    For each camera named, ``<folder>/<camera>_blender_uv.exr``: for each
    plate pixel, the pixel of the overscan render (the add-on's frame of
    ``W + 2 mx`` by ``H + 2 my``, margins from its ``overscan_margins``) to
    sample, ``U = (x + 0.5) / (W + 2 mx)``, ``V = 1 - (y + 0.5) / (H + 2 my)``
    (:func:`camcal.geometry.stmap.st_from_pixels` on that frame; pixel (0, 0) at
    the centre of the top-left pixel), ``x`` the lens's undistorted pixel
    (:func:`camcal.geometry.stmap.undistorted_grid`) plus the margin; blue is
    Map UV's mask (1, or 0 where the lens has no undistorted pixel), as in
    Blender's UV render pass.

    Returns
    -------
    dict
        Camera name -> path, for the add-on's ``import_rig(uv_maps=...)``.
    """
    from camcal.geometry.stmap import st_from_pixels, undistorted_grid
    from camcal.io.stmap import write_exr

    margins = importlib.import_module(f"{load_addon().__name__}.tracking").overscan_margins  # pure: no bpy
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    paths = {}
    for name in names:
        camera = rig.camera(name)
        (width, height), (mx, my) = camera.image_size, margins(camera.image_size, overscan)
        x, y = undistorted_grid(camera.distortion, camera.K, camera.image_size)
        uv = st_from_pixels(x + mx, y + my, (width + 2 * mx, height + 2 * my))
        uv[..., 2] = np.isfinite(x) & np.isfinite(y)  # Map UV's mask, as in Blender's UV pass
        paths[name] = str(write_exr(folder / f"{name}_blender_uv.exr", uv))
    return paths


def import_rig_to_blend(rig: str | os.PathLike, blend: str | os.PathLike | None = None, *,
                        into: str | os.PathLike | None = None, replace: bool = True, **options) -> dict:
    """Import a rig file into a new .blend file, or into an existing one (written atomically).

    Parameters
    ----------
    rig : path
        The ``*.rig.json`` file.
    blend : path, optional
        The .blend file to write (default: ``into``, updated in place).
    into : path, optional
        An existing .blend file to add the rig to (its active scene);
        default: a new, empty file.
    replace : bool
        An earlier import of the same rig file in the scene is replaced in
        place (the add-on's ``reimport.import_in_place``: same collection
        name and parent collections, the user's objects parented to the rig
        kept on it) instead of adding a second collection.
    **options
        Keyword options of the add-on's ``import_rig`` (``up_axis``,
        ``sensor_fit``, ``use_rectified``, ``import_plates``,
        ``import_points``, ``stereo``, ``distortion``, ``compositor``,
        ``overscan``...).

    Returns
    -------
    dict
        A summary: rig name, its ``collection``, whether it ``replaced`` an
        earlier import, the ``scene``, camera objects, stereo mode, clips,
        warnings; ``conversions``: one line per lens replaced by its nearest
        fit (:func:`blender_tracking_rig`), its residual in pixels (also
        first among the warnings).

    Raises
    ------
    CamcalError
        A bad rig file, .blend file or options (one line naming it), or no bpy.
    """
    check_installed("bpy")
    if blend is None and into is None:
        raise CamcalError("give the .blend file to write, or an existing one to import into")
    rig = Path(rig).resolve()
    into = Path(into).resolve() if into is not None else None
    blend = Path(blend).resolve() if blend is not None else into
    if not rig.is_file():
        raise CamcalError(f"rig file not found: {rig}")
    if into is not None and not into.is_file():
        raise CamcalError(f".blend file to import into not found: {into}")
    if not blend.parent.is_dir():
        raise CamcalError(f"output folder does not exist: {blend.parent}")
    options.setdefault("aux_directory", str(blend.parent / f"{blend.stem}_lens"))
    source = Rig.load(rig)
    tracking, conversions = blender_tracking_rig(source, options.get("overscan", 1.1))
    exact_maps = [c.camera for c in conversions if not tracking.camera(c.camera).distortion.is_fisheye]
    if exact_maps and options.get("distortion", True) and options.get("compositor", True):
        options["uv_maps"] = write_blender_uv_maps(source, exact_maps, options["aux_directory"],
                                                   options.get("overscan", 1.1))
    fitted = None
    if conversions:  # the refitted rig beside the original, so that its relative paths still hold
        handle, name = tempfile.mkstemp(prefix=f".{rig.stem}.", suffix=".blender.rig.json", dir=rig.parent)
        os.close(handle)
        fitted = Path(name)
        tracking.save(fitted)
        # the add-on names the collection and objects after the rig's "name", else its file: keep the original's
        stand_in = json.loads(fitted.read_text(encoding="utf-8"))
        stand_in["name"] = next((rig.name[:-len(end)] for end in (".rig.json", ".json") if rig.name.endswith(end)),
                                rig.name)
        fitted.write_text(json.dumps(stand_in), encoding="utf-8")
    payload = json.dumps({"rig": str(fitted or rig), "source": str(rig), "blend": str(blend),
                          "into": str(into) if into is not None else None, "replace": replace, "options": options})
    env = dict(os.environ)
    env.setdefault("CAMCAL_ADDON_DIR", str(addon_dir()))
    try:
        proc = subprocess.run(
            [sys.executable, "-c", _SCRIPT, payload], capture_output=True, text=True, env=env
        )
    finally:
        if fitted is not None:
            fitted.unlink(missing_ok=True)
    if proc.returncode != 0:
        lines = [line for line in proc.stderr.strip().splitlines() if line.strip()]
        message = lines[-1] if lines else f"Blender import failed (exit code {proc.returncode})"
        raise CamcalError(message)
    for line in proc.stdout.splitlines():
        if line.startswith("CAMCAL_RESULT "):
            summary = json.loads(line[len("CAMCAL_RESULT "):])
            summary["conversions"] = [conversion.describe() for conversion in conversions]
            summary["warnings"] = summary["conversions"] + summary["warnings"]
            return summary
    raise CamcalError("Blender import finished without a result")


def extension_tool() -> Path:
    """Blender's extension command-line tool (``blender_ext.py``) shipped in the bpy wheel."""
    check_installed("bpy")
    spec = importlib.util.find_spec("bpy")
    tools = sorted(Path(spec.origin).parent.glob("*/scripts/addons_core/bl_pkg/cli/blender_ext.py"))
    if not tools:
        raise CamcalError(f"blender_ext.py not found in the bpy package at {Path(spec.origin).parent}")
    return tools[-1]


def build_extension(output_dir: str | os.PathLike = "dist") -> Path:
    """Validate the add-on and build its extension zip with Blender's own tool.

    Returns the path of the zip (``camcal_rig-<version>.zip``), itself
    validated after the build.
    """
    tool = extension_tool()
    source = addon_dir()
    output = Path(output_dir).resolve()
    output.mkdir(parents=True, exist_ok=True)

    def run(*args):
        proc = subprocess.run([sys.executable, str(tool), *args], capture_output=True, text=True)
        if proc.returncode != 0:
            lines = (proc.stdout + proc.stderr).strip().splitlines()
            raise CamcalError(f"blender_ext {args[0]} failed: {lines[-1] if lines else proc.returncode}")
        return proc.stdout

    run("validate", str(source))
    before = set(output.glob("*.zip"))
    log = run("build", "--source-dir", str(source), "--output-dir", str(output))
    created = [line.split('"')[1] for line in log.splitlines() if line.startswith("created:")]
    zip_path = Path(created[0]) if created else max(set(output.glob("*.zip")) - before)
    run("validate", str(zip_path))
    return zip_path


if __name__ == "__main__":  # ``python -m camcal.blender_bridge [DIST]``: build the extension zip
    try:
        print(build_extension(sys.argv[1] if len(sys.argv) > 1 else "dist"))
    except CamcalError as error:
        print(f"camcal: error: {error}", file=sys.stderr)
        sys.exit(2)
