"""Colour characterisation: charts, linearisation, models, evaluation, spectral.

The hand-off to the rest of camcal is the fit file ``*.colour.json``
(:mod:`camcal.colour.fitfile` documents it)::

    from camcal.colour import load_fit
    fit = load_fit("cam.colour.json")
    XYZ = fit.apply(RGB_linear)       # (N, 3) linear camera RGB -> XYZ, white Y = 1
    XYZ = fit.apply_codes(codes)      # (N, 3) code values in [0, 1] -> XYZ
    RGB_linear = fit.linearise(codes)

Modules: ``chart`` (reference charts, cv2.mcc detection, sampling),
``linearise`` (per-channel curves), ``models`` (matrix3x3, polynomial,
root-polynomial, rbf), ``select`` (``--model auto``), ``evaluate`` (Delta E
statistics, leave-one-out, plots), ``spectral`` (simulated cameras,
sensitivity estimation, mu-factor, chromatic adaptation), ``patches`` (patch
CSV), ``characterise`` (the ``colour fit`` pipeline), ``fitfile`` (the file),
``match`` (camera-to-camera matching: chart and stereo routes), ``match_models``,
``robust``, ``matchfile`` (its file kind, listed in ``fitfile.FILE_KINDS``).
"""

from camcal.colour.fitfile import ColourFit, load_colour_file, load_fit
from camcal.colour.matchfile import ColourMatch, load_match

__all__ = ["ColourFit", "ColourMatch", "load_fit", "load_colour_file", "load_match"]
