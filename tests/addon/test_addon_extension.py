"""The extension zip: Blender's tool validates and builds it; it installs, enables,
registers and unregisters headless (bpy module, temporary user folders)."""

import os
import subprocess
import sys
import textwrap
import zipfile

import pytest

from camcal.blender_bridge import build_extension


def test_zip_builds_installs_enables_and_disables(tmp_path):
    pytest.importorskip("bpy")
    zip_path = build_extension(tmp_path / "dist")
    assert zip_path.name == "camcal_rig-0.1.0.zip"
    names = set(zipfile.ZipFile(zip_path).namelist())
    assert {"blender_manifest.toml", "__init__.py", "importer.py", "mapping.py"} <= names
    assert not any("__pycache__" in n for n in names)
    script = textwrap.dedent(
        """
        import sys, bpy
        mod = "bl_ext.user_default.camcal_rig"
        def enabled():
            return mod in {a.module for a in bpy.context.preferences.addons}
        bpy.ops.wm.read_factory_settings(use_empty=True)
        assert bpy.ops.extensions.package_install_files(
            repo="user_default", filepath=sys.argv[1], enable_on_install=True) == {"FINISHED"}
        assert enabled() and hasattr(bpy.types, "VIEW3D_PT_camcal")
        assert hasattr(bpy.ops.import_scene, "camcal_rig")
        assert sys.modules[mod].import_rig.__module__ == mod + ".importer"
        bpy.ops.preferences.addon_disable(module=mod)
        assert not enabled() and not hasattr(bpy.types, "VIEW3D_PT_camcal")
        bpy.ops.preferences.addon_enable(module=mod)
        assert enabled() and hasattr(bpy.types, "VIEW3D_PT_camcal")
        print("ok")
        """
    )
    home = tmp_path / "home"
    home.mkdir()
    env = dict(os.environ, HOME=str(home), BLENDER_USER_RESOURCES=str(home / "blender"))
    proc = subprocess.run([sys.executable, "-c", script, str(zip_path)], capture_output=True, text=True, env=env)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    assert proc.stdout.strip().endswith("ok")
    assert (home / "blender" / "extensions" / "user_default" / "camcal_rig" / "importer.py").is_file()
