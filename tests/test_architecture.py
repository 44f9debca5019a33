"""The house's contract (pyproject.toml [tool.importlinter], ARCHITECTURE.md) holds.

import-linter builds the import graph of camcal (lazy imports inside
functions included) and checks three contracts: the layers from the CLI down
to the primitives, no import circle between sibling modules at any depth, and
no file access from the pure maths (geometry/, colour/).
"""

import os
import shutil
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def lint(package_root: Path) -> subprocess.CompletedProcess:
    """Run import-linter with the repository's contracts on the camcal found under ``package_root``."""
    code = ("import sys; from importlinter.cli import lint_imports; "
            f"sys.exit(lint_imports(config_filename={str(ROOT / 'pyproject.toml')!r}, no_cache=True))")
    env = {**os.environ, "PYTHONPATH": str(package_root)}
    return subprocess.run([sys.executable, "-c", code], cwd=package_root, env=env,
                          capture_output=True, text=True, timeout=300)


def test_the_import_contracts_hold():
    run = lint(ROOT)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "3 kept, 0 broken" in run.stdout


def test_the_contract_sees_an_upward_import(tmp_path):
    """A copy of camcal whose data model imports the CLI (lazily) breaks the layers contract."""
    shutil.copytree(ROOT / "camcal", tmp_path / "camcal", ignore=shutil.ignore_patterns("__pycache__"))
    rig = tmp_path / "camcal" / "model" / "rig.py"
    rig.write_text(rig.read_text() + "\n\ndef upward():\n    from camcal.cli import main\n    return main\n")
    run = lint(tmp_path)
    assert run.returncode == 1, run.stdout + run.stderr
    assert "camcal.model is not allowed to import camcal.cli" in run.stdout
