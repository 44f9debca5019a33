"""OpenColorIO releases side by side, for loading camcal's configs as the hosts that link them do.

``python tests/colour/export/ocio_releases.py install DIR`` (run by ``make test``)
puts each release of :data:`RELEASES` into ``DIR/<major.minor>`` with pip's
``--target`` (wheels from PyPI, no dependencies: PyOpenColorIO needs none)
and writes ``DIR/<major.minor>/interpreter``, the Python that imports it.
OpenColorIO 2.3 has no wheel for Python 3.13, so it is installed for the
newest of Python 3.12 / 3.11 / 3.10 found on the machine (PATH, pyenv,
/usr/bin); without one it is left out with a warning (its test then skips,
or fails in CI). A release already installed is left as it is.

The test (``test_ocio_versions.py`` beside this file) finds them with :func:`installed`.
"""

from __future__ import annotations

import glob
import os
import shutil
import subprocess
import sys
from pathlib import Path

#: The releases the hosts camcal exports to link: Blender 4.2 LTS and the VFX Reference Platform CY2024
#: (2.3), CY2025 (2.4), Blender 5.2 and CY2026 (2.5). The test venv's own release (2.6) is the fourth.
RELEASES = {"2.3": "2.3.2", "2.4": "2.4.2", "2.5": "2.5.0"}

#: Python versions tried, in order, for a release without a wheel for the running interpreter.
FALLBACK_PYTHONS = ("3.12", "3.11", "3.10")


def versions_dir() -> Path:
    """``ocio`` in the running virtual environment (where ``make test`` installs the releases)."""
    return Path(sys.prefix) / "ocio"


def installed(root: Path | None = None) -> dict[str, tuple[str, Path]]:
    """``{"2.3": (interpreter, folder), ...}`` of the releases installed under ``root``."""
    root = versions_dir() if root is None else root
    found = {}
    for minor in RELEASES:
        marker = root / minor / "interpreter"
        if marker.is_file() and (root / minor / "PyOpenColorIO").is_dir():
            found[minor] = (marker.read_text().strip(), root / minor)
    return found


def _runs(python: str, version: str) -> bool:
    code = f"import sys; sys.exit(sys.version_info[:2] != {tuple(int(p) for p in version.split('.'))})"
    try:
        return subprocess.run([python, "-c", code], capture_output=True, timeout=60).returncode == 0
    except (OSError, subprocess.SubprocessError):
        return False


def find_python(version: str) -> str | None:
    """An interpreter of Python ``version`` (``"3.12"``) on this machine, or None."""
    candidates = [shutil.which(f"python{version}")]
    candidates += sorted(glob.glob(os.path.expanduser(f"~/.pyenv/versions/{version}*/bin/python{version}")),
                         reverse=True)
    candidates += [f"/usr/local/bin/python{version}", f"/usr/bin/python{version}"]
    for python in candidates:
        if python and Path(python).is_file() and _runs(python, version):
            return python
    return None


def _pip_target(release: str, folder: Path, python_version: str) -> bool:
    command = [sys.executable, "-m", "pip", "install", "--quiet", "--disable-pip-version-check", "--no-deps",
               "--only-binary=:all:", "--python-version", python_version, "--target", str(folder),
               f"opencolorio=={release}"]
    return subprocess.run(command, capture_output=True, text=True).returncode == 0


def install(root: Path) -> None:
    """Install every release of :data:`RELEASES` under ``root`` that is not there yet."""
    here = f"{sys.version_info.major}.{sys.version_info.minor}"
    present = installed(root)
    for minor, release in RELEASES.items():
        if minor in present:
            continue
        folder = root / minor
        shutil.rmtree(folder, ignore_errors=True)
        for python_version in (here, *FALLBACK_PYTHONS):
            python = sys.executable if python_version == here else find_python(python_version)
            if python is None:
                continue
            if _pip_target(release, folder, python_version):
                (folder / "interpreter").write_text(python + "\n")
                print(f"OpenColorIO {release} for Python {python_version} in {folder}")
                break
            shutil.rmtree(folder, ignore_errors=True)
        else:
            # not fatal here: the test names the missing release (and fails under CAMCAL_REQUIRE_OCIO_VERSIONS=1)
            print(f"camcal: OpenColorIO {release} not installed: no wheel for Python {here} and no Python "
                  f"{' / '.join(FALLBACK_PYTHONS)} with one found (install Python 3.12)", file=sys.stderr)


if __name__ == "__main__":
    if len(sys.argv) != 3 or sys.argv[1] != "install":
        raise SystemExit("usage: python tests/colour/export/ocio_releases.py install DIR")
    install(Path(sys.argv[2]))
