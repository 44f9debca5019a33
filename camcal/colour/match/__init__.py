"""Match stage: camera-to-camera colour matching (chart and stereo routes) and its record.

Modules: ``models`` (:class:`Lut3DModel`, :func:`parse_match_model`),
``robust`` (:func:`fit_match_model`: LMedS + IRLS), ``routes``
(:func:`match_charts`, :func:`match_correspondences`), ``record``
(:class:`ColourMatch`, the data of a ``match`` file).
"""

from camcal.colour.match.models import Lut3DModel, parse_match_model
from camcal.colour.match.record import ColourMatch
from camcal.colour.match.robust import fit_match_model
from camcal.colour.match.routes import match_charts, match_correspondences

__all__ = ["match_charts", "match_correspondences", "fit_match_model", "parse_match_model", "Lut3DModel",
           "ColourMatch"]
