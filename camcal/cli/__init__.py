"""The ``camcal`` command: one module per verb, each parsing its options and calling the library.

Every verb prints a short human summary and writes its outputs atomically.
:data:`camcal.cli.app.VERBS` wires the verbs in (name -> module, imported
only when that verb runs); a verb's module holds its options and its call
into the library (imported inside the handler, so ``camcal --help`` starts
fast); the options several verbs share are written once in
:mod:`camcal.cli.options`, the summary and exit codes in
:mod:`camcal.cli.summary`.

Errors, for every verb and every input:

- a malformed command line (:class:`~camcal.cli.options.UsageError`: an
  option missing or malformed, a flag given without the one it needs) prints
  ``camcal <verb>: error: <reason>`` and ``see 'camcal <verb> --help'`` on
  stderr and returns 2;
- a user's mistake (:class:`~camcal.base.errors.CamcalError`, an ``OSError`` on a
  path the user gave, a file that does not decode) prints one line
  ``camcal: error: ...`` on stderr and exits with code 2;
- an internal error (a bug in camcal) prints one line naming the verb and
  "run with --debug for the traceback" and exits with code 1;
- ``--debug`` (before or after the verb) shows the full traceback instead.

One option name means one thing in every verb (``--images`` the inputs,
``--camera`` the rig camera a verb acts on, ``--camera-name`` the name a
file records, ``--board`` the target, ``--adaptation`` the chromatic
adaptation); former spellings still parse, with a one-line note
(:func:`~camcal.cli.options.deprecated_option`).

Options that name cameras take ``NAME=VALUE`` entries
(:class:`~camcal.cli.options.NamedValues`): ``--images left=A right=B`` is
the same as ``--images left=A --images right=B``; a name given twice, an
entry without ``=`` or a glob that matches nothing is one error line naming
the option and the entry. Globs may be absolute or relative
(:func:`~camcal.cli.options.expand_glob`).

``--json`` (every verb) prints one versioned JSON object on stdout instead
of the human summary (which then goes to stderr)::

    {"format": "camcal.summary", "version": 1, "camcal": "0.x",
     "verb": "rectify", "exit_code": 0,
     "figures": {...the summary's numbers, named with their units...},
     "files": [{"path": "out/rect.rig.json", "kind": "rig"}, ...],
     "warnings": [...]}

and on an error ``{"...", "exit_code": 2, "error": "the one line"}`` (for a
malformed command line, the reason without ``camcal <verb>: error:``).
Handlers record figures and files on :func:`summary_of(args)
<camcal.cli.summary.summary_of>` (:class:`~camcal.cli.summary.VerbSummary`).
"""

from camcal.cli.app import build_parser, main

__all__ = ["build_parser", "main"]
