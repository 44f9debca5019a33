"""``camcal colour fit | export | match | sensitivities | flatfield``: one module per sub-verb."""

from __future__ import annotations

import argparse
import importlib

from camcal.cli.options import verb_group

__all__ = ["SUBVERBS", "register"]

#: sub-verb (its module here) -> its line in ``camcal colour --help``.
SUBVERBS = {
    "fit": "fit a characterisation from a chart photo or a patch CSV",
    "export": "export fits as OCIO colour spaces (config + CLF) and ICC camera profiles",
    "match": "match one camera's colours to another's (stereo pair or chart)",
    "sensitivities": "estimate (or load measured) camera spectral sensitivities: *.ssf.json + CSV",
    "flatfield": "fit a lens's flat field and vignetting from grey cards: JSON, gain EXR, Lensfun entry",
}


def register(parser: argparse.ArgumentParser) -> None:
    """The ``colour`` group: each sub-verb's module fills its parser."""
    parser.description = "Colour characterisation of a camera: charts, linearisation, models, Delta E."
    verbs = verb_group(parser, "colour_verb", "SUBVERB")
    for name, help_line in SUBVERBS.items():
        importlib.import_module(f"camcal.cli.colour.{name}").register(verbs.add_parser(name, help=help_line))
