"""Optional dependencies: the extras table agrees with pyproject.toml, and a missing one is one line naming it.

A missing module is simulated with ``sys.modules[name] = None`` (Python's own way
to make ``import name`` fail with ``ModuleNotFoundError``).
"""

import functools
import importlib.metadata
import re
import sys
import tomllib
from pathlib import Path

import cv2
import numpy as np
import pytest
from packaging.requirements import Requirement

from camcal.base.extras import EXTRAS, MissingExtraError, check_installed, missing_extra, require
from camcal.cli import main

ROOT = Path(__file__).resolve().parents[2]
PROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]


def _name(requirement: str) -> str:
    return re.sub(r"[-_.]+", "-", Requirement(requirement).name).lower()


def _distributions(extra: str) -> set[str]:
    """The distributions an extra installs, its ``camcal[...]`` references followed."""
    names = set()
    for line in PROJECT["optional-dependencies"][extra]:
        requirement = Requirement(line)
        if requirement.name == "camcal":
            for other in requirement.extras:
                names |= _distributions(other)
        else:
            names.add(_name(line))
    return names


@functools.cache
def _providers() -> dict[str, list[str]]:
    return importlib.metadata.packages_distributions()


def _hide(monkeypatch, *modules: str) -> None:
    for name in modules:
        for loaded in [key for key in sys.modules if key == name or key.startswith(f"{name}.")]:
            monkeypatch.delitem(sys.modules, loaded)
        monkeypatch.setitem(sys.modules, name, None)


@pytest.mark.parametrize("module", sorted(EXTRAS))
def test_each_optional_module_is_installed_by_its_extra_and_not_by_the_light_install(module):
    providers = {re.sub(r"[-_.]+", "-", name).lower()
                 for name in _providers().get(module, [])}
    assert providers, f"{module} is not installed here: make test installs every extra"
    assert providers & _distributions(EXTRAS[module]), (module, EXTRAS[module], providers)
    assert not providers & {_name(line) for line in PROJECT["dependencies"]}, f"{module} is in the light install"


def test_every_extra_but_test_is_in_the_table_and_all_holds_every_one_but_blender():
    extras = set(PROJECT["optional-dependencies"]) - {"test", "all"}
    assert extras == set(EXTRAS.values())
    assert _distributions("all") == set().union(*(_distributions(e) for e in extras - {"blender"}))


def test_no_runtime_dependency_is_pinned_exactly():
    lines = PROJECT["dependencies"] + [line for extra, lines in PROJECT["optional-dependencies"].items()
                                       if extra != "test" for line in lines]
    for line in lines:
        specifiers = Requirement(line).specifier
        assert not any(s.operator in ("==", "===") for s in specifiers), line
        assert Requirement(line).name == "camcal" or any(s.operator == ">=" for s in specifiers), line


def test_the_lock_pins_every_distribution_the_extras_install_and_each_pin_is_in_range():
    lock = {}
    for line in (ROOT / "requirements" / "lock-py313.txt").read_text().splitlines():
        if line and not line.startswith("#"):
            name, _, version = line.partition("==")
            lock[re.sub(r"[-_.]+", "-", name).lower()] = version
    lines = PROJECT["dependencies"] + [line for lines in PROJECT["optional-dependencies"].values() for line in lines]
    for line in lines:
        requirement = Requirement(line)
        if requirement.name == "camcal" or not (requirement.marker is None or requirement.marker.evaluate()):
            continue
        name = _name(line)
        assert name in lock, f"{name} is not in the lock"
        assert requirement.specifier.contains(lock[name], prereleases=True), (line, lock[name])


@pytest.mark.parametrize("module", ["pycolmap", "pyceres", "colour", "PyOpenColorIO", "rawpy", "matplotlib.pyplot",
                                    "distributed", "pxr"])
def test_a_missing_module_is_one_line_naming_its_extra(monkeypatch, module):
    top = module.partition(".")[0]
    _hide(monkeypatch, top)
    with pytest.raises(MissingExtraError) as info:
        require(module)
    line, extra = str(info.value), EXTRAS[top]
    assert "\n" not in line
    assert f"needs the '{extra}' extra ({top} is not installed)" in line
    assert line.endswith(f"pip install 'camcal[{extra}]'")


def test_an_installed_module_is_returned():
    assert require("rawpy") is sys.modules["rawpy"]


def test_a_missing_submodule_of_an_installed_package_is_a_broken_install_not_an_extra():
    assert missing_extra(ModuleNotFoundError("No module named 'colour.nowhere'", name="colour.nowhere")) is None
    assert missing_extra(ModuleNotFoundError("No module named 'notcamcal'", name="notcamcal")) is None
    with pytest.raises(ValueError, match="numpy is not an optional module of camcal"):
        require("numpy")


def test_bpy_is_checked_without_importing_it(monkeypatch):
    _hide(monkeypatch, "bpy")
    with pytest.raises(MissingExtraError, match=r"the 'blender' extra \(bpy is not installed\)"):
        check_installed("bpy")


def test_camcal_solve_without_the_calibrate_extra_says_so_in_one_line(monkeypatch, tmp_path, capsys):
    folder = tmp_path / "cam"
    folder.mkdir()
    rng = np.random.default_rng(0)
    for index in range(2):
        cv2.imwrite(str(folder / f"{index:02d}.png"), rng.integers(0, 255, (48, 64), dtype=np.uint8))
    _hide(monkeypatch, "pycolmap", "pyceres")
    code = main(["solve", str(folder), "--out", str(tmp_path / "solve")])
    out, err = capsys.readouterr()
    assert code == 2
    assert err.splitlines() == [f"camcal: error: camcal solve needs the 'calibrate' extra (pycolmap is not installed): "
                                f"pip install 'camcal[calibrate]'"]
    assert not (tmp_path / "solve").exists()


def test_a_bare_import_of_a_missing_extra_still_gives_the_one_line(monkeypatch, capsys):
    """The CLI's net: a ModuleNotFoundError of an optional module, wherever it is raised, names the extra."""
    from camcal.model.rig import Rig

    def load(path):
        import pxr  # noqa: F401 - the import under test

    monkeypatch.setattr(Rig, "load", staticmethod(load))
    _hide(monkeypatch, "pxr")
    assert main(["rig", "show", "any.rig.json"]) == 2
    assert capsys.readouterr().err.splitlines() == [
        "camcal: error: camcal rig show needs the 'usd' extra (pxr is not installed): pip install 'camcal[usd]'"]


def test_pycolmap_required_before_opencv_leaves_opencv_able_to_write_png(tmp_path):
    """pycolmap's extension carries its own libpng / zlib: imported before OpenCV, OpenCV's PNG writer aborts
    ("double free"). ``require("pycolmap")`` imports OpenCV first, so the PNGs are written and read back equal."""
    import subprocess
    import textwrap

    script = textwrap.dedent(f"""
        from camcal.base.extras import require
        require("pycolmap")
        import cv2, numpy as np
        image = (np.random.default_rng(0).random((120, 160, 3)) * 255).astype(np.uint8)
        for index in range(5):
            path = {str(tmp_path)!r} + f"/{{index}}.png"
            assert cv2.imwrite(path, image) and (cv2.imread(path) == image).all()
        print("written")
    """)
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0 and run.stdout.strip() == "written", run.stderr[-2000:]
