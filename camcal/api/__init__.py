"""camcal's public Python API: one function per verb of the ``camcal`` command, the same defaults and errors.

The command's handlers parse their options, call these functions and print
their results; a script, a headless Blender session or a farm job calls the
same functions (also importable from :mod:`camcal` itself).
"""

__all__: list[str] = []
