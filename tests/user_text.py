"""What user-facing text (README, docs, ``--help``, the demo's output) must not hold.

Internal references mean nothing to a user: a tracker's issue numbers ("issue 27",
"#27" as an issue), development vocabulary ("must-show") and paths of the machine the
project is developed on (``/work/...``, ``../shared/...``, a home or temporary folder
named as where data comes from). :func:`internal_references` lists what it finds, so a
failing test names the offending words.
"""

from __future__ import annotations

import re

__all__ = ["internal_references"]

_PATTERNS = (
    re.compile(r"\bissues? \d+", re.IGNORECASE),
    re.compile(r"(?<![\w&/])#\d+\b"),  # "#27" as an issue; not "&#39;" (HTML) nor "a/#1" (URL fragments)
    re.compile(r"\bmust[- ]shows?\b", re.IGNORECASE),
    re.compile(r"(?<![\w.])/work/"),
    re.compile(r"\.\./shared\b"),
    re.compile(r"(?<![\w.])/root\b"),
    re.compile(r"(?<![\w.])/home/\w"),
    re.compile(r"(?<![\w.])/tmp/\w"),
)


def internal_references(text: str, *, allowed_prefixes: tuple[str, ...] = ()) -> list[str]:
    """Every internal reference in ``text``: issue numbers, development words, machine paths.

    Parameters
    ----------
    text : str
        User-facing text.
    allowed_prefixes : tuple of str
        Paths the text may name (e.g. the output folder a test gave a run), removed first.

    Returns
    -------
    list of str
        Each offending match with a little context, in order; empty when the text is clean.
    """
    for prefix in allowed_prefixes:
        text = text.replace(prefix, "DIR")
    # an HTML page's style sheets hold colours such as #333, not issue numbers
    text = re.sub(r"<style.*?</style>", "", text, flags=re.DOTALL)
    text = re.sub(r"""style=("[^"]*"|'[^']*')""", "", text)
    found = []
    for pattern in _PATTERNS:
        for match in pattern.finditer(text):
            start, end = max(0, match.start() - 30), min(len(text), match.end() + 30)
            found.append(text[start:end].replace("\n", " "))
    return found
