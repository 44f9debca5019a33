"""Running the Blender add-on's importer from camcal, without importing bpy here.

``camcal blender import RIG --blend OUT.blend`` runs the add-on's
``import_rig`` in a subprocess of the same Python interpreter, which has
the ``bpy`` module (the ``blender`` extra): camcal itself never imports bpy,
and Blender's global state stays out of the calling process.

The add-on lives in ``addon/`` beside the ``camcal`` package (a source
checkout or editable install); ``CAMCAL_ADDON_DIR`` overrides the location.
"""

from __future__ import annotations

import importlib.util
import json
import os
import subprocess
import sys
from pathlib import Path

from camcal import resources
from camcal.base.errors import CamcalError
from camcal.base.extras import check_installed

__all__ = [
    "ADDON_PACKAGE",
    "addon_dir",
    "load_addon",
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
bpy.ops.wm.read_factory_settings(use_empty=True)
scene = bpy.context.scene
try:
    result = addon.import_rig(scene, args["rig"], **args["options"])
except (RigFileError, OSError, ValueError) as error:
    print(str(error), file=sys.stderr)
    sys.exit(2)
out = args["blend"]
tmp = os.path.join(os.path.dirname(out), "." + os.path.basename(out) + ".tmp.blend")
bpy.ops.wm.save_as_mainfile(filepath=tmp, check_existing=False, copy=True)
os.replace(tmp, out)
summary = {
    "rig": result.rig.name,
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


def import_rig_to_blend(rig: str | os.PathLike, blend: str | os.PathLike, **options) -> dict:
    """Import a rig file into a new .blend file (written atomically).

    Parameters
    ----------
    rig : path
        The ``*.rig.json`` file.
    blend : path
        The .blend file to write.
    **options
        Keyword options of the add-on's ``import_rig`` (``up_axis``,
        ``sensor_fit``, ``use_rectified``, ``import_plates``,
        ``import_points``, ``stereo``, ``distortion``, ``compositor``,
        ``overscan``...).

    Returns
    -------
    dict
        A summary: rig name, camera objects, stereo mode, clips, warnings.

    Raises
    ------
    CamcalError
        A bad rig file or options (the add-on's one-line message), or no bpy.
    """
    check_installed("bpy")
    rig = Path(rig).resolve()
    blend = Path(blend).resolve()
    if not rig.is_file():
        raise CamcalError(f"rig file not found: {rig}")
    if not blend.parent.is_dir():
        raise CamcalError(f"output folder does not exist: {blend.parent}")
    options.setdefault("aux_directory", str(blend.parent / f"{blend.stem}_lens"))
    payload = json.dumps({"rig": str(rig), "blend": str(blend), "options": options})
    env = dict(os.environ)
    env.setdefault("CAMCAL_ADDON_DIR", str(addon_dir()))
    proc = subprocess.run(
        [sys.executable, "-c", _SCRIPT, payload], capture_output=True, text=True, env=env
    )
    if proc.returncode != 0:
        lines = [line for line in proc.stderr.strip().splitlines() if line.strip()]
        message = lines[-1] if lines else f"Blender import failed (exit code {proc.returncode})"
        raise CamcalError(message)
    for line in proc.stdout.splitlines():
        if line.startswith("CAMCAL_RESULT "):
            return json.loads(line[len("CAMCAL_RESULT "):])
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
