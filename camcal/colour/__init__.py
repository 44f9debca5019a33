"""Colour characterisation in stages: pure maths on arrays and dataclasses (no files).

Sub-packages, bottom up (each imports only those before it):

- :mod:`~camcal.colour.difference`: CIELAB, Delta E and their statistics;
- :mod:`~camcal.colour.spectral`: spectral data, simulated cameras,
  sensitivity estimation, illuminants, chromatic adaptation;
- :mod:`~camcal.colour.chart`: reference charts, detection and sampling,
  patch sets, linearisation;
- :mod:`~camcal.colour.bake`: a colour function as OCIO transforms (matrix
  or shaper + Lut3D) and where its bake must hold;
- :mod:`~camcal.colour.fit`: characterisation models, fitting, ``auto``
  selection, evaluation, fits for another illuminant, the fit record;
- :mod:`~camcal.colour.match`: camera-to-camera matching and its record;
- :mod:`~camcal.colour.export`: OCIO colour spaces and Looks, ICC profiles.

Beside them, :mod:`~camcal.colour.flatfield` (with :mod:`~camcal.colour.flatfield_samples`): a lens's flat field
and vignetting from grey cards or neutral patches, applied before a fit.

The files (``*.colour.json``, ``*.ssf.json``, patch CSVs, OCIO configs, ICC
profiles, chart images) are read and written by :mod:`camcal.io`; the steps
from paths to files are in :mod:`camcal.pipelines.colour`::

    from camcal.io.colourfile import load_fit
    fit = load_fit("cam.colour.json")
    XYZ = fit.apply(RGB_linear)       # (N, 3) linear camera RGB -> XYZ, white Y = 1
    XYZ = fit.apply_codes(codes)      # (N, 3) code values in [0, 1] -> XYZ
    RGB_linear = fit.linearise(codes)
"""

__all__: list[str] = []
