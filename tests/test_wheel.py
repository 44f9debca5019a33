"""The wheel works on its own: built, installed in a fresh venv, add-on and OCIO base found.

Slow (a wheel build and a venv with every dependency from pip's configured
index); the fast check below covers the resource lookup in this install.
"""

import sys
import zipfile
from pathlib import Path

import pytest

from camcal.resources import addon_dir, ocio_configs_dir
from camcal.model.rig import Rig
from camcal.synthetic import example_camera
from fresh_venv import make_venv, run

ROOT = Path(__file__).resolve().parents[1]


def test_resources_found_with_importlib():
    assert (addon_dir() / "blender_manifest.toml").is_file()
    assert (ocio_configs_dir() / "camcal_base.ocio").is_file()


@pytest.mark.slow
def test_wheel_in_a_fresh_venv_imports_into_blender_and_exports_ocio(tmp_path, sim):
    dist = tmp_path / "dist"
    run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-q", "-w", dist, ROOT], cwd=tmp_path, check=True)
    [wheel] = dist.glob("camcal-*.whl")
    names = zipfile.ZipFile(wheel).namelist()
    assert "camcal/resources/addon/blender_manifest.toml" in names
    assert "camcal/resources/ocio_configs/camcal_base.ocio" in names
    venv = make_venv(tmp_path / "venv")
    venv.pip_install("-c", ROOT / "requirements" / "lock-py313.txt", f"{wheel}[all,blender]", cwd=tmp_path)
    camcal, env = venv.camcal, venv.env
    # the installed package, not this checkout
    where = run([venv.python, "-c", "import camcal, camcal.resources as r; print(camcal.__file__); print(r.addon_dir())"],
                cwd=tmp_path, env=env, check=True).stdout.split()
    assert all(str(venv.path) in line for line in where), where

    rig = Rig((example_camera("left", image_size=(320, 240), fx=300, fy=300, principal_point=(159.5, 119.5)),))
    rig_path = rig.save(tmp_path / "one.rig.json")
    run([camcal, "blender", "import", rig_path, "--blend", tmp_path / "one.blend"], cwd=tmp_path, env=env, check=True)
    assert (tmp_path / "one.blend").stat().st_size > 0

    from camcal.colour.fit.characterise import characterise
    from camcal.colour.chart.patches import PatchSet
    from camcal.io.colourfile import save_colour_file

    fit = characterise(PatchSet(sim.names_train, sim.RGB_train, sim.XYZ_train), white="D65", model="matrix3x3",
                       loo=False).fit
    fit_path = save_colour_file(fit, tmp_path / "cam.colour.json")
    run([camcal, "colour", "export", fit_path, "--ocio", tmp_path / "ocio", "--base", "camcal"], cwd=tmp_path, env=env,
        check=True)
    assert "camcal" in (tmp_path / "ocio" / "config.ocio").read_text()
