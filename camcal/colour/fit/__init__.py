"""Fit stage: characterisation models, fitting, ``auto`` selection, evaluation, the fit record.

Modules: ``terms`` (term sets, :func:`parse_model_spec`), ``models``
(:class:`LinearTermsModel`, :class:`RBFModel`), ``fitting`` (the dispatcher
:func:`fit_model`), ``select`` (:func:`select_model`), ``evaluate``
(:func:`evaluate_model`), ``characterise`` (:func:`characterise`),
``illuminant`` (:func:`characterise_for_illuminant`), ``record``
(:class:`ColourFit`, the data of a ``*.colour.json``).
"""

from camcal.colour.fit.characterise import characterise
from camcal.colour.fit.evaluate import evaluate_model
from camcal.colour.fit.fitting import fit_model
from camcal.colour.fit.illuminant import characterise_for_illuminant
from camcal.colour.fit.models import LinearTermsModel, RBFModel
from camcal.colour.fit.record import ColourFit
from camcal.colour.fit.select import select_model
from camcal.colour.fit.terms import parse_model_spec

__all__ = ["fit_model", "parse_model_spec", "LinearTermsModel", "RBFModel", "select_model", "evaluate_model",
           "characterise", "characterise_for_illuminant", "ColourFit"]
