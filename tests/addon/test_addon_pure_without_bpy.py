"""The add-on's pure part loads and works where bpy cannot be imported."""

import subprocess
import sys
import textwrap

from addon_helpers import ADDON_DIR


def test_pure_modules_need_no_bpy_or_numpy():
    script = textwrap.dedent(
        f"""
        import sys, importlib.util
        sys.modules['bpy'] = None      # any 'import bpy' now fails
        sys.modules['numpy'] = None
        spec = importlib.util.spec_from_file_location(
            'camcal_rig', {str(ADDON_DIR / '__init__.py')!r},
            submodule_search_locations=[{str(ADDON_DIR)!r}])
        mod = importlib.util.module_from_spec(spec)
        sys.modules['camcal_rig'] = mod
        spec.loader.exec_module(mod)
        from camcal_rig import fisheye, mapping, rigfile, plyfile, pngfile, overlay, tracking, solvejob
        b = mapping.blender_intrinsics([[1000, 0, 959.5], [0, 1000, 539.5], [0, 0, 1]], (1920, 1080))
        assert abs(b.lens - 18.75) < 1e-12
        assert 'camcal' not in sys.modules
        print('ok')
        """
    )
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout.strip() == "ok"
