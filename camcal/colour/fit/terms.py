"""Model terms and names: Cheung (2004) and Finlayson (2015) term sets, term parsing, ``--model`` specs.

Terms are written as strings: ``"1"``, ``"R"``, ``"R*G"``, ``"R^2*G"`` for
polynomials and ``"(R*G)^(1/2)"``, ``"(R*G^2)^(1/3)"`` for root terms. Root
terms use sign-preserving powers (``sign(x) |x|^p``), as colour-science
does, so slightly negative noisy inputs stay finite. The models themselves
are in :mod:`camcal.colour.fit.models`.

References
----------
- Cheung, V., Westland, S., Connah, D., Ripamonti, C. (2004). A comparative
  study of the characterisation of colour cameras by means of neural networks
  and polynomial transforms. Coloration Technology, 120(1), 19-25.
- Finlayson, G. D., Mackiewicz, M., Hurlbert, A. (2015). Color Correction
  Using Root-Polynomial Regression. IEEE TIP, 24(5), 1460-1470.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import numpy as np

from camcal.base.errors import CamcalError

__all__ = [
    "MODEL_KINDS",
    "OBJECTIVES",
    "RBF_KERNELS",
    "CHEUNG_TERMS",
    "ModelSpec",
    "parse_model_spec",
    "terms_Cheung2004",
    "terms_Finlayson2015",
    "parse_term",
    "expand",
    "nonlinear_mask",
]


MODEL_KINDS = ("matrix3x3", "polynomial", "root-polynomial", "rbf")
#: ``xyz+de2000`` is the mean of the ``xyz`` and ``de2000`` fits (same terms, same ``lambda``): one
#: linear-terms model, the model average ``auto`` adds (:mod:`camcal.colour.fit.select`).
OBJECTIVES = ("xyz", "de2000", "xyz+de2000")
RBF_KERNELS = ("polyharmonic-1", "polyharmonic-3", "thin-plate")

# Exponents (R, G, B) of Cheung et al. (2004) term sets, in colour-science's
# order (``matrix_augmented_Cheung2004``); (0, 0, 0) is the constant term.
_C = {
    "R": (1, 0, 0), "G": (0, 1, 0), "B": (0, 0, 1), "1": (0, 0, 0),
    "RG": (1, 1, 0), "RB": (1, 0, 1), "GB": (0, 1, 1), "RGB": (1, 1, 1),
    "R2": (2, 0, 0), "G2": (0, 2, 0), "B2": (0, 0, 2),
    "R2G": (2, 1, 0), "G2B": (0, 2, 1), "B2R": (1, 0, 2),
    "R2B": (2, 0, 1), "G2R": (1, 2, 0), "B2G": (0, 1, 2),
    "R3": (3, 0, 0), "G3": (0, 3, 0), "B3": (0, 0, 3),
    "R2GB": (2, 1, 1), "RG2B": (1, 2, 1), "RGB2": (1, 1, 2),
    "R3G": (3, 1, 0), "R3B": (3, 0, 1), "G3R": (1, 3, 0), "G3B": (0, 3, 1),
    "B3R": (1, 0, 3), "B3G": (0, 1, 3),
    "R2G2": (2, 2, 0), "R2B2": (2, 0, 2), "G2B2": (0, 2, 2),
    "R4": (4, 0, 0), "G4": (0, 4, 0), "B4": (0, 0, 4),
}
_BASE = ["R", "G", "B"]
_PAIRS = ["RG", "RB", "GB"]
_SQUARES = ["R2", "G2", "B2"]
_CUBIC6 = ["R2G", "G2B", "B2R"]
_CUBIC6B = ["R2B", "G2R", "B2G"]
_CUBES = ["R3", "G3", "B3"]
_CHEUNG_NAMES: dict[int, list[str]] = {
    3: _BASE,
    4: _BASE + ["1"],
    5: _BASE + ["RGB", "1"],
    7: _BASE + _PAIRS + ["1"],
    8: _BASE + _PAIRS + ["RGB", "1"],
    10: _BASE + _PAIRS + _SQUARES + ["1"],
    11: _BASE + _PAIRS + _SQUARES + ["RGB", "1"],
    14: _BASE + _PAIRS + _SQUARES + ["RGB"] + _CUBES + ["1"],
    16: _BASE + _PAIRS + _SQUARES + ["RGB"] + _CUBIC6 + _CUBES,
    17: _BASE + _PAIRS + _SQUARES + ["RGB"] + _CUBIC6 + _CUBES + ["1"],
    19: _BASE + _PAIRS + _SQUARES + ["RGB"] + _CUBIC6 + _CUBIC6B + _CUBES,
    20: _BASE + _PAIRS + _SQUARES + ["RGB"] + _CUBIC6 + _CUBIC6B + _CUBES + ["1"],
    22: _BASE + _PAIRS + _SQUARES + ["RGB"] + _CUBIC6 + _CUBIC6B + _CUBES
    + ["R2GB", "RG2B", "RGB2"],
    35: _BASE + _PAIRS + _SQUARES + ["RGB"] + _CUBIC6 + _CUBIC6B + _CUBES
    + ["R3G", "R3B", "G3R", "G3B", "B3R", "B3G", "R2GB", "RG2B", "RGB2",
       "R2G2", "R2B2", "G2B2", "R4", "G4", "B4", "1"],
}
CHEUNG_TERMS = tuple(sorted(_CHEUNG_NAMES))

# Finlayson et al. (2015) root-polynomial exponents, colour-science's order.
_FINLAYSON: dict[int, list[tuple[int, int, int]]] = {}
_F1 = [(1, 0, 0), (0, 1, 0), (0, 0, 1)]
_F2 = [(1, 1, 0), (0, 1, 1), (1, 0, 1)]
_F3 = [(1, 2, 0), (0, 1, 2), (1, 0, 2), (2, 1, 0), (0, 2, 1), (2, 0, 1), (1, 1, 1)]
_F4 = [(3, 1, 0), (3, 0, 1), (1, 3, 0), (0, 3, 1), (1, 0, 3), (0, 1, 3),
       (2, 1, 1), (1, 2, 1), (1, 1, 2)]
_FINLAYSON[1] = _F1
_FINLAYSON[2] = _F1 + _F2
_FINLAYSON[3] = _F1 + _F2 + _F3
_FINLAYSON[4] = _F1 + _F2 + _F3 + _F4

_TERM_RE = re.compile(
    r"^(?:1|(?P<poly>[RGB](?:\^[0-9])?(?:\*[RGB](?:\^[0-9])?)*)"
    r"|\((?P<root>[RGB](?:\^[0-9])?(?:\*[RGB](?:\^[0-9])?)*)\)\^\(1/(?P<n>[0-9])\))$"
)


def _monomial(exponents: tuple[int, int, int]) -> str:
    parts = []
    for letter, e in zip("RGB", exponents):
        if e == 1:
            parts.append(letter)
        elif e > 1:
            parts.append(f"{letter}^{e}")
    return "*".join(parts) if parts else "1"


def _term_name(exponents: tuple[int, int, int], root: bool) -> str:
    degree = sum(exponents)
    if not root or degree <= 1:
        return _monomial(exponents)
    return f"({_monomial(exponents)})^(1/{degree})"


def terms_Cheung2004(n_terms: int) -> tuple[str, ...]:
    """The *Cheung et al. (2004)* polynomial term set with ``n_terms`` terms.

    Parameters
    ----------
    n_terms
        One of 3, 4, 5, 7, 8, 10, 11, 14, 16, 17, 19, 20, 22, 35.

    Returns
    -------
    tuple of str
        Term names in colour-science's order, e.g. 10 gives
        ``('R', 'G', 'B', 'R*G', 'R*B', 'G*B', 'R^2', 'G^2', 'B^2', '1')``.

    Examples
    --------
    >>> terms_Cheung2004(4)
    ('R', 'G', 'B', '1')
    """
    if n_terms not in _CHEUNG_NAMES:
        raise CamcalError(
            f"no Cheung 2004 polynomial with {n_terms} terms, expected one of: "
            + ", ".join(str(n) for n in CHEUNG_TERMS)
        )
    return tuple(_monomial(_C[name]) for name in _CHEUNG_NAMES[n_terms])


def terms_Finlayson2015(degree: int) -> tuple[str, ...]:
    """The *Finlayson et al. (2015)* root-polynomial terms of ``degree`` 1-4.

    Examples
    --------
    >>> terms_Finlayson2015(2)
    ('R', 'G', 'B', '(R*G)^(1/2)', '(G*B)^(1/2)', '(R*B)^(1/2)')
    """
    if degree not in _FINLAYSON:
        raise CamcalError(f"no root-polynomial of degree {degree}, expected 1, 2, 3 or 4")
    return tuple(_term_name(e, True) for e in _FINLAYSON[degree])


def parse_term(term: str) -> tuple[tuple[int, int, int], bool]:
    """Exponents and root flag of a canonical term string."""
    match = _TERM_RE.match(term) if isinstance(term, str) else None
    if match is None:
        raise CamcalError(f"malformed model term {term!r}")
    body = match.group("poly") or match.group("root")
    exponents = [0, 0, 0]
    if body:
        for factor in body.split("*"):
            letter, _, power = factor.partition("^")
            exponents["RGB".index(letter)] += int(power or 1)
    exps = (exponents[0], exponents[1], exponents[2])
    root = match.group("root") is not None
    if root and int(match.group("n")) != sum(exps):
        raise CamcalError(f"malformed model term {term!r}: the root must equal the degree")
    if _term_name(exps, root) != term:
        raise CamcalError(
            f"model term {term!r} is not in canonical form {_term_name(exps, root)!r}"
        )
    return exps, root


def expand(RGB: np.ndarray, terms: tuple[str, ...] | list[str]) -> np.ndarray:
    """Evaluate ``terms`` on linear camera RGB.

    Parameters
    ----------
    RGB
        Linear camera RGB, shape ``(..., 3)``.
    terms
        Canonical term strings (see the module docstring).

    Returns
    -------
    numpy.ndarray
        Shape ``(..., T)``.

    Examples
    --------
    >>> expand(np.array([[0.5, 0.2, 0.8]]), ("R", "R*G", "(R*G)^(1/2)", "1")).round(6).tolist()
    [[0.5, 0.1, 0.316228, 1.0]]
    """
    RGB = np.asarray(RGB, dtype=np.float64)
    R, G, B = RGB[..., 0], RGB[..., 1], RGB[..., 2]
    columns = []
    for term in terms:
        (a, b, c), root = parse_term(term)
        value = np.ones_like(R)
        for channel, e in ((R, a), (G, b), (B, c)):
            if e:
                value = value * channel**e
        if root and a + b + c > 1:
            value = np.sign(value) * np.abs(value) ** (1.0 / (a + b + c))
        columns.append(value)
    return np.stack(columns, axis=-1)


def nonlinear_mask(terms: tuple[str, ...]) -> np.ndarray:
    """True for terms the ridge penalty applies to: total degree > 1 (root or not)."""
    mask = []
    for term in terms:
        (a, b, c), root = parse_term(term)
        mask.append(a + b + c > 1)
    return np.array(mask, dtype=bool)


# --------------------------------------------------------------------------
# Model specification ("polynomial:10", "root-polynomial:2", ...)


@dataclass(frozen=True)
class ModelSpec:
    """What to fit: a model kind and its order / kernel.

    ``order`` is the number of Cheung terms for ``polynomial``, the degree
    for ``root-polynomial``; ``kernel`` is the RBF kernel.
    """

    kind: str
    order: int | None = None
    white_preserving: bool = False
    kernel: str = "polyharmonic-1"

    def terms(self) -> tuple[str, ...]:
        """The term list of a linear-terms model."""
        if self.kind == "matrix3x3":
            return ("R", "G", "B")
        if self.kind == "polynomial":
            return terms_Cheung2004(int(self.order or 10))
        if self.kind == "root-polynomial":
            return terms_Finlayson2015(int(self.order or 2))
        raise CamcalError(f"model {self.kind!r} has no term list")

    @property
    def label(self) -> str:
        """The spec as the CLI writes it, e.g. ``polynomial:10``."""
        if self.kind == "matrix3x3":
            return "matrix3x3:white-preserving" if self.white_preserving else "matrix3x3"
        if self.kind == "rbf":
            return f"rbf:{self.kernel}"
        suffix = ":white-preserving" if self.white_preserving else ""
        return f"{self.kind}:{self.order}{suffix}"


def parse_model_spec(text: str) -> ModelSpec:
    """Parse a model name as the CLI takes it.

    Accepted: ``matrix3x3``, ``matrix3x3:white-preserving``,
    ``polynomial[:N]`` (N Cheung terms, default 10), ``root-polynomial[:D]``
    (degree D, default 2), ``rbf[:KERNEL]`` (``polyharmonic-1``,
    ``polyharmonic-3``, ``thin-plate``); ``:white-preserving`` may follow
    a polynomial or root-polynomial too.

    Examples
    --------
    >>> parse_model_spec("polynomial:10")
    ModelSpec(kind='polynomial', order=10, white_preserving=False, kernel='polyharmonic-1')
    """
    parts = str(text).strip().split(":")
    kind = parts[0]
    if kind not in MODEL_KINDS:
        raise CamcalError(
            f"unknown model {text!r}, expected one of: auto, matrix3x3, "
            "polynomial:N, root-polynomial:D, rbf[:KERNEL]"
        )
    options = parts[1:]
    white_preserving = "white-preserving" in options or "wp" in options
    options = [o for o in options if o not in ("white-preserving", "wp")]
    if kind == "rbf":
        if white_preserving:
            raise CamcalError("rbf models cannot be white preserving")
        kernel = options[0] if options else "polyharmonic-1"
        if kernel not in RBF_KERNELS or len(options) > 1:
            raise CamcalError(
                f"unknown RBF kernel in {text!r}, expected one of: {', '.join(RBF_KERNELS)}"
            )
        return ModelSpec("rbf", None, False, kernel)
    if kind == "matrix3x3":
        if options:
            raise CamcalError(f"matrix3x3 takes no order, got {text!r}")
        return ModelSpec("matrix3x3", None, white_preserving)
    if len(options) > 1:
        raise CamcalError(f"malformed model {text!r}")
    try:
        order = int(options[0]) if options else (10 if kind == "polynomial" else 2)
    except ValueError:
        raise CamcalError(f"malformed model order in {text!r}, expected an integer") from None
    spec = ModelSpec(kind, order, white_preserving)
    spec.terms()  # validates the order
    return spec
