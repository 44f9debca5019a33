"""OCIO config templates (``*.ocio``) that camcal fills with fitted camera colour spaces.

A package only so that :mod:`importlib.resources` finds the folder in an
installed wheel (``camcal.resources.ocio_configs``, see ``setup.py``).
"""
