"""Private names stay in their module: no ``from camcal.x import _name`` across modules."""

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def private_imports(path: Path) -> list[str]:
    """``module._name`` for every ``from camcal... import _name`` and ``camcal_module._name`` use in a file."""
    tree = ast.parse(path.read_text(), str(path))
    found = []
    for node in ast.walk(tree):
        if isinstance(node, ast.ImportFrom) and (node.module or "").startswith("camcal"):
            found += [f"{node.module}.{alias.name}" for alias in node.names if alias.name.startswith("_")
                      and not alias.name.startswith("__")]
    return found


def test_no_private_name_is_imported_across_camcal_modules():
    offenders = {}
    for path in sorted([*(ROOT / "camcal").rglob("*.py"), *(ROOT / "bench").glob("*.py")]):
        names = private_imports(path)
        if names:
            offenders[str(path.relative_to(ROOT))] = names
    assert offenders == {}, f"make these public in the module that owns them: {offenders}"


def test_the_check_sees_a_private_import(tmp_path):
    sample = tmp_path / "sample.py"
    sample.write_text("from camcal.colour.spectral import _resample\nfrom camcal.model.rig import Rig\n")
    assert private_imports(sample) == ["camcal.colour.spectral._resample"]
