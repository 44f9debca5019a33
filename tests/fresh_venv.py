"""A fresh virtual environment for the install tests (test_light_install, test_wheel, test_quickstart).

Made with this interpreter's base Python (``python -m venv``), with nothing of
this checkout on its path: the environment of its commands drops
``PYTHONPATH`` and camcal's resource overrides, and puts the venv's ``bin``
first on ``PATH`` (so ``camcal`` and ``pip`` are the venv's, as after
activating it).
"""

from __future__ import annotations

import os
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

__all__ = ["FreshVenv", "make_venv", "run"]

#: variables that would point a fresh install back at this checkout
_CHECKOUT_VARIABLES = ("PYTHONPATH", "CAMCAL_ADDON_DIR", "CAMCAL_OCIO_CONFIGS")


def run(argv: list, cwd: Path, env: dict | None = None, check: bool = False) -> subprocess.CompletedProcess:
    """Run ``argv`` (paths allowed) in ``cwd``; ``check``: fail the test with the command and its output."""
    result = subprocess.run([str(a) for a in argv], cwd=cwd, capture_output=True, text=True, env=env)
    if check:
        assert result.returncode == 0, f"{' '.join(map(str, argv))}\n{result.stdout}\n{result.stderr}"
    return result


@dataclass(frozen=True)
class FreshVenv:
    """A virtual environment and the environment variables its commands run with."""

    path: Path
    env: dict[str, str]

    @property
    def python(self) -> Path:
        return self.path / "bin" / "python"

    @property
    def camcal(self) -> Path:
        return self.path / "bin" / "camcal"

    def pip_install(self, *arguments: object, cwd: Path) -> None:
        """``python -m pip install -q ARGUMENTS`` in the venv; fails the test with pip's output."""
        run([self.python, "-m", "pip", "install", "-q", *arguments], cwd, self.env, check=True)

    def installed(self) -> set[str]:
        """The distributions installed in the venv, names normalised (``usd-core``, ``colour-science``)."""
        listed = run([self.python, "-m", "pip", "list", "--format=freeze"], self.path, self.env, check=True)
        return {line.split("==")[0].lower().replace("_", "-") for line in listed.stdout.splitlines() if "==" in line}

    def camcal_location(self) -> str:
        """Where the venv's ``import camcal`` comes from."""
        return run([self.python, "-c", "import camcal; print(camcal.__file__)"], self.path, self.env,
                   check=True).stdout.strip()


def make_venv(folder: Path) -> FreshVenv:
    """A new virtual environment in ``folder`` (this interpreter's Python 3.13), nothing installed but pip."""
    run([sys.executable, "-m", "venv", folder], folder.parent, check=True)
    env = {k: v for k, v in os.environ.items() if k not in _CHECKOUT_VARIABLES}
    env["PATH"] = f"{folder / 'bin'}{os.pathsep}{env.get('PATH', '')}"
    env["VIRTUAL_ENV"] = str(folder)
    return FreshVenv(folder, env)
