"""camcal rig importer: Blender extension (4.2+) that imports camcal rig files.

Layout: pure-Python modules that need neither bpy nor numpy (:mod:`.rigfile`,
:mod:`.mapping`, :mod:`.tracking`, :mod:`.fisheye`, :mod:`.plyfile`,
:mod:`.pngfile`, :mod:`.solvejob`) and a thin bpy layer (:mod:`.importer`, :mod:`.lens_animation`,
:mod:`.reimport`, :mod:`.operators`, :mod:`.solve_clip`, :mod:`.panel`). This file
imports no bpy at module level, so the pure modules load without Blender.

From a script (``blender -b --python-expr`` or ``import bpy``)::

    import importlib
    camcal_rig = importlib.import_module("bl_ext.user_default.camcal_rig")
    camcal_rig.import_rig(bpy.context.scene, "/path/to/stereo.rig.json")
"""

__all__ = ["register", "unregister", "import_rig"]


def __getattr__(name):
    # ``import_rig`` without importing bpy when only the pure modules are used.
    if name == "import_rig":
        from .importer import import_rig

        return import_rig
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def register():
    from . import lens_animation, operators, panel, solve_clip

    operators.register()
    solve_clip.register()
    panel.register()
    lens_animation.register()


def unregister():
    from . import lens_animation, operators, panel, solve_clip

    lens_animation.unregister()
    panel.unregister()
    solve_clip.unregister()
    operators.unregister()
