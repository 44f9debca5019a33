"""Write requirements/lowest-py313.txt: every direct dependency pinned at its lowest allowed version.

``python requirements/lowest.py > requirements/lowest-py313.txt`` (tests/test_quickstart.py
checks the file is current). The pins are the lower bounds of pyproject.toml's
ranges, for the dependencies and the extras ``make test`` installs
(``all``, ``blender``, ``test``), except where that bound has no wheel for
CPython 3.13 on Linux x86_64 or is not installable beside the rest:
:data:`PY313_FLOORS` says which and why (the bounds themselves stay, for
Python 3.11). ``make test-lowest`` installs the set as constraints, so pip
takes the newest compatible release of every dependency of a dependency
(uv's ``--resolution lowest-direct``).
"""

from __future__ import annotations

import sys
import tomllib
from pathlib import Path

from packaging.requirements import Requirement
from packaging.utils import canonicalize_name
from packaging.version import Version

__all__ = ["EXTRAS", "PY313_FLOORS", "direct_requirements", "lower_bound", "lowest_pins", "main", "render"]

PYPROJECT = Path(__file__).resolve().parents[1] / "pyproject.toml"
#: the extras `make test` installs
EXTRAS = ("all", "blender", "test")
#: name -> (lowest version installable on CPython 3.13, why it is above pyproject's bound)
PY313_FLOORS: dict[str, tuple[str, str]] = {
    "numpy": ("2.2.0", "bpy 5.1.1 requires numpy>=2.2 (1.26 has no Python 3.13 wheels)"),
    "opencv-contrib-python-headless": ("4.11.0.86", "the first 4.11 release"),
    "openexr": ("3.4.0", "3.3 has no Python 3.13 wheels"),
    "pyyaml": ("6.0.2", "the first release with Python 3.13 wheels"),
    "matplotlib": ("3.9.2", "the first release with Python 3.13 wheels"),
    "opencolorio": ("2.4.0", "2.3 has no Python 3.13 wheels"),
    "openimageio": ("3.0.3.1", "the first 3.0 release on PyPI with Python 3.13 wheels"),
    "bpy": ("5.1.1", "5.0.1 is for Python 3.11; 5.1.0 requires numpy<2, which has no Python 3.13 wheels"),
    "pillow": ("10.4.0", "the first release with Python 3.13 wheels"),
}


def direct_requirements(project: dict) -> list[Requirement]:
    """The requirements of the package and of :data:`EXTRAS`, with camcal's own extras expanded."""
    optional = project["optional-dependencies"]
    found, pending, seen = list(map(Requirement, project["dependencies"])), list(EXTRAS), set()
    while pending:
        extra = pending.pop()
        if extra in seen:
            continue
        seen.add(extra)
        for requirement in map(Requirement, optional[extra]):
            if canonicalize_name(requirement.name) == canonicalize_name(project["name"]):
                pending.extend(requirement.extras)
            else:
                found.append(requirement)
    return found


def lower_bound(requirement: Requirement) -> Version:
    """The version of the requirement's ``>=`` clause; a requirement without one is an error."""
    bounds = [Version(spec.version) for spec in requirement.specifier if spec.operator == ">="]
    if len(bounds) != 1:
        raise SystemExit(f"{requirement}: needs exactly one '>=' lower bound to be tested at")
    return bounds[0]


def lowest_pins(pyproject: Path = PYPROJECT) -> dict[str, tuple[str, str]]:
    """``{name: (version, reason)}``: the lowest allowed version of every direct dependency (reason "" = the bound)."""
    project = tomllib.loads(pyproject.read_text())["project"]
    pins: dict[str, tuple[str, str]] = {}
    for requirement in direct_requirements(project):
        name = canonicalize_name(requirement.name)
        bound = lower_bound(requirement)
        version, reason = PY313_FLOORS.get(name, (str(bound), ""))
        if reason and not (Version(version) > bound and requirement.specifier.contains(version)):
            raise SystemExit(f"{name}: floor {version} is not above the bound {bound} inside {requirement.specifier}; "
                             "drop or update its entry in PY313_FLOORS")
        pins[name] = (version, reason)
    return dict(sorted(pins.items()))


def render(pins: dict[str, tuple[str, str]]) -> str:
    """The text of requirements/lowest-py313.txt."""
    lines = ["# The lowest versions pyproject.toml allows, for `make test-lowest` (Python 3.13, Linux x86_64):",
             "# every direct dependency pinned at its lower bound, or at the first release installable there.",
             "# Generated: python requirements/lowest.py > requirements/lowest-py313.txt"]
    for name, (version, reason) in pins.items():
        lines.append(f"{name}=={version}" + (f"  # {reason}" if reason else ""))
    return "\n".join(lines) + "\n"


def main() -> int:
    """Print the file to stdout."""
    sys.stdout.write(render(lowest_pins()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
