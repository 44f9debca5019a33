"""Shared pieces of the colour export tests: fits of the simulated camera, OpenColorIO releases and Blender reading
a config."""

import json
import os
import subprocess
import sys
import textwrap

import colour
import numpy as np
import pytest

from camcal.colour.fit.characterise import characterise
from camcal.colour.chart.patches import PatchSet
from ocio_releases import RELEASES, installed

GAMMA = 2.2  # the simulated camera's encoding: code = linear ** (1 / 2.2)


def codes_of(RGB):
    return np.clip(RGB, 0.0, 1.0) ** (1.0 / GAMMA)


def make_fit(sim, model, linearise="gamma-offset", target_white=None, camera="nikon"):
    """A characterisation of the simulated Nikon from gamma-encoded code values."""
    train = PatchSet(sim.names_train, codes_of(sim.RGB_train), sim.XYZ_train)
    test = PatchSet(sim.names_test, codes_of(sim.RGB_test), sim.XYZ_test)
    return characterise(train, white="D65", model=model, linearise=linearise, test=test,
                        target_white=target_white, camera=camera, loo=False).fit


def needs_ocio_writing(profile):
    """Skip unless the installed OpenColorIO writes profile ``profile`` (``"2.5"``): a release writes its own and older.

    The reason names the release needed, from the installed one's version (``make test-lowest`` runs 2.4).
    """
    import PyOpenColorIO as ocio

    if tuple(int(part) for part in ocio.__version__.split(".")[:2]) < tuple(int(part) for part in profile.split(".")):
        pytest.skip(f"needs OpenColorIO {profile} or newer (profile {profile}); installed: {ocio.__version__}")


def code_grid(n=9):
    g = np.linspace(0.0, 1.0, n)
    return np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)


BLENDER_SCRIPT = textwrap.dedent(
    """
    import json, sys
    import numpy as np
    import bpy
    args = json.loads(sys.argv[1])
    items = bpy.types.ColorManagedInputColorspaceSettings.bl_rna.properties["name"].enum_items
    print("CAMCAL_LISTED " + json.dumps([i.identifier for i in items]))
    codes = np.asarray(args["codes"], dtype=np.float32)
    H, W = codes.shape[:2]
    image = bpy.data.images.new("codes", W, H, alpha=True, float_buffer=True)
    image.colorspace_settings.name = "Raw"
    pixels = np.ones((H, W, 4), np.float32)
    pixels[..., :3] = codes
    image.pixels.foreach_set(pixels.ravel())
    image.filepath_raw = args["exr"]
    image.file_format = "OPEN_EXR"
    image.save()
    plate = bpy.data.images.load(args["exr"])
    plate.colorspace_settings.name = args["space"]
    plate.reload()
    out = np.empty(H * W * 4, np.float32)
    plate.pixels.foreach_get(out)
    print("CAMCAL_PIXELS " + json.dumps(out.reshape(H, W, 4)[..., :3].tolist()))
    """
)


def blender_reads(config_path, space, codes, folder):
    """Blender (bpy in a subprocess, ``$OCIO`` = the config) lists its input spaces and reads ``codes`` as ``space``.

    ``codes`` ``(H, W, 3)`` are saved as an EXR in Blender's ``Raw`` space and
    loaded back as ``space``; returns (the input space names Blender lists,
    the loaded pixels ``(H * W, 3)`` in Blender's scene-linear space).
    """
    args = {"codes": np.asarray(codes).tolist(), "exr": str(folder / "codes.exr"), "space": space}
    env = dict(os.environ, OCIO=str(config_path))
    proc = subprocess.run([sys.executable, "-c", BLENDER_SCRIPT, json.dumps(args)], capture_output=True, text=True,
                          env=env, timeout=300)
    assert proc.returncode == 0, proc.stderr
    lines = {line.split(" ", 1)[0]: json.loads(line.split(" ", 1)[1]) for line in proc.stdout.splitlines()
             if line.startswith("CAMCAL_")}
    return lines["CAMCAL_LISTED"], np.asarray(lines["CAMCAL_PIXELS"]).reshape(-1, 3)


LOADER = textwrap.dedent(
    """
    import json, sys
    import PyOpenColorIO as ocio
    args = json.loads(sys.argv[1])
    out = {"release": ocio.__version__}
    try:
        config = ocio.Config.CreateFromFile(args["config"])
        config.validate()
    except Exception as error:
        out["error"] = str(error)
        print(json.dumps(out))
        sys.exit(0)
    out["profile"] = [config.getMajorVersion(), config.getMinorVersion()]
    aces = config.getRoleColorSpace("aces_interchange")
    flat = [value for rgb in args["codes"] for value in rgb]
    out["spaces"] = {}
    for name in args["spaces"]:
        space = config.getColorSpace(name)
        cpu = config.getProcessor(name, aces).getDefaultCPUProcessor()
        out["spaces"][name] = {"family": space.getFamily(), "aces": cpu.applyRGB(list(flat))}
    print(json.dumps(out))
    """
)


def releases():
    """``{"2.3": (interpreter, folder), ...}`` for every side-by-side release, or skip / fail when one is missing."""
    found = installed()
    missing = [minor for minor in RELEASES if minor not in found]
    if missing:
        reason = (f"OpenColorIO {', '.join(missing)} not installed side by side in {sys.prefix}/ocio "
                  f"(make test installs them: tests/colour/export/ocio_releases.py install)")
        if os.environ.get("CAMCAL_REQUIRE_OCIO_VERSIONS") == "1":
            pytest.fail(reason)
        pytest.skip(reason)
    return found


def load_in_release(minor, config_path, codes, spaces):
    """Load, validate and convert ``codes`` through ``spaces`` with OpenColorIO ``minor`` (``"2.6"``: this venv's).

    A subprocess of :data:`LOADER` with ``PYTHONPATH`` set to the release's
    folder (:mod:`ocio_releases`); returns its JSON (``release``,
    ``profile``, per space ``family`` and ``aces``, or ``error``).
    """
    if minor == "2.6":
        python, env = sys.executable, dict(os.environ)
    else:
        python, folder = releases()[minor]
        env = dict(os.environ, PYTHONPATH=str(folder), PYTHONNOUSERSITE="1")
    args = {"config": str(config_path), "codes": np.asarray(codes).tolist(), "spaces": list(spaces)}
    proc = subprocess.run([python, "-c", LOADER, json.dumps(args)], capture_output=True, text=True, env=env,
                          timeout=120)
    assert proc.returncode == 0, proc.stderr
    return json.loads(proc.stdout.splitlines()[-1])


def ACES_to_XYZ(ACES, white_XYZ):
    """ACES2065-1 to XYZ under ``white_XYZ`` (colour-science, Bradford)."""
    return colour.RGB_to_XYZ(ACES, colour.RGB_COLOURSPACES["ACES2065-1"], colour.XYZ_to_xy(white_XYZ),
                             chromatic_adaptation_transform="Bradford")
