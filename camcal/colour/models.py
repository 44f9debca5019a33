"""Characterisation models: linear camera RGB to CIE XYZ.

Four model kinds, each a frozen dataclass with ``apply(RGB) -> XYZ``,
``to_dict()`` / ``from_dict()`` (the ``model`` block of ``*.colour.json``)
and a fitting function behind one dispatcher, :func:`fit_model`:

``matrix3x3``
    ``XYZ = M @ RGB``; optionally white preserving (``M @ RGB_w = XYZ_w``
    exactly, for the camera RGB ``RGB_w`` of the perfect white).
``polynomial``
    ``XYZ = M @ expand(RGB)`` with a *Cheung et al. (2004)* term set
    (3, 4, 5, 7, 8, 10, 11, 14, 16, 17, 19, 20, 22 or 35 terms; 10 is the
    seed's ``R, G, B, RG, RB, GB, R^2, G^2, B^2, 1``).
``root-polynomial``
    ``XYZ = M @ expand(RGB)`` with the *Finlayson et al. (2015)* root terms
    of degree 1 to 4: every term has total degree 1, so the model is
    exposure invariant (``f(k RGB) = k f(RGB)``).
``rbf``
    ``XYZ = sum_j w_j phi(|RGB - c_j|) + L @ [R, G, B, 1]``: a polyharmonic
    radial basis function network on top of a linear (affine) part
    (*Thomas 2011*), with a smoothing term ``lambda`` added to the kernel
    diagonal and chosen by leave-one-out cross-validation.

Conventions
-----------
- ``RGB`` is *linear* camera RGB, shape ``(N, 3)``; ``XYZ`` is relative
  CIE XYZ with ``Y = 1`` for the perfect white of the target space.
- Coefficient matrices are stored ``(3, T)``, one row per output X, Y, Z,
  so ``XYZ = M @ expand(RGB)`` as in colour-science's
  ``matrix_colour_correction``; for ``matrix3x3`` this is the usual 3x3
  matrix an OCIO ``MatrixTransform`` takes.
- Terms are written as strings: ``"1"``, ``"R"``, ``"R*G"``, ``"R^2*G"``
  for polynomials and ``"(R*G)^(1/2)"``, ``"(R*G^2)^(1/3)"`` for root terms.
  Root terms use sign-preserving powers (``sign(x) |x|^p``), as
  colour-science does, so slightly negative noisy inputs stay finite.

Objectives: ``"xyz"`` (regularised linear least squares in XYZ, closed form)
or ``"de2000"`` (sum of squared CIEDE2000 per patch, minimised by
``scipy.optimize.least_squares`` from the least-squares solution; not
available for ``rbf``). Regularisation ``lambda`` is a ridge penalty on the
non-linear terms only: ``|A M^T - XYZ|^2 / N + lambda |M_nl|^2``.

References
----------
- Cheung, V., Westland, S., Connah, D., Ripamonti, C. (2004). A comparative
  study of the characterisation of colour cameras by means of neural networks
  and polynomial transforms. Coloration Technology, 120(1), 19-25.
- Finlayson, G. D., Mackiewicz, M., Hurlbert, A. (2015). Color Correction
  Using Root-Polynomial Regression. IEEE TIP, 24(5), 1460-1470.
- Thomas, J.-B. et al. (2011). Colorimetric characterization of digital
  cameras using radial basis functions (thin-plate / polyharmonic splines).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import Any

import numpy as np

from camcal.base.errors import CamcalError

__all__ = [
    "MODEL_KINDS",
    "OBJECTIVES",
    "RBF_KERNELS",
    "CHEUNG_TERMS",
    "ModelSpec",
    "LinearTermsModel",
    "RBFModel",
    "parse_model_spec",
    "terms_Cheung2004",
    "terms_Finlayson2015",
    "expand",
    "fit_model",
    "fit_linear_terms",
    "fit_rbf",
    "delta_E2000_components",
    "model_from_dict",
    "parse_term",
]

MODEL_KINDS = ("matrix3x3", "polynomial", "root-polynomial", "rbf")
OBJECTIVES = ("xyz", "de2000")
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


def _nonlinear_mask(terms: tuple[str, ...]) -> np.ndarray:
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


# --------------------------------------------------------------------------
# Models


def _as_rgb(RGB: Any) -> tuple[np.ndarray, tuple[int, ...]]:
    RGB = np.asarray(RGB, dtype=np.float64)
    if RGB.shape[-1:] != (3,):
        raise CamcalError(f"camera RGB must have shape (N, 3), got {RGB.shape}")
    return RGB.reshape(-1, 3), RGB.shape


@dataclass(frozen=True, eq=False)
class LinearTermsModel:
    """``XYZ = M @ expand(RGB, terms)``: matrix3x3, polynomial, root-polynomial.

    Attributes
    ----------
    kind
        ``"matrix3x3"``, ``"polynomial"`` or ``"root-polynomial"``.
    terms
        Term strings, length T.
    M
        ``(3, T)`` coefficients, rows X, Y, Z.
    white_preserving
        Whether the fit was constrained to map the camera white to the
        target white exactly.
    objective, regularisation
        How it was fitted (recorded in the file).
    """

    kind: str
    terms: tuple[str, ...]
    M: np.ndarray
    white_preserving: bool = False
    objective: str = "xyz"
    regularisation: float = 0.0

    def __post_init__(self) -> None:
        M = np.array(self.M, dtype=np.float64)
        M.setflags(write=False)
        object.__setattr__(self, "M", M)
        object.__setattr__(self, "terms", tuple(self.terms))
        if M.shape != (3, len(self.terms)):
            raise CamcalError(
                f"model coefficients must have shape (3, {len(self.terms)}), got {M.shape}"
            )

    @property
    def label(self) -> str:
        """Short description, e.g. ``root-polynomial:2 (de2000)``."""
        if self.kind == "matrix3x3":
            name = "matrix3x3"
        elif self.kind == "polynomial":
            name = f"polynomial:{len(self.terms)}"
        else:
            degree = max(sum(parse_term(t)[0]) for t in self.terms)
            name = f"root-polynomial:{degree}"
        if self.white_preserving:
            name += ":white-preserving"
        return name

    def apply(self, RGB: Any) -> np.ndarray:
        """Map linear camera RGB ``(..., 3)`` to XYZ ``(..., 3)``."""
        flat, shape = _as_rgb(RGB)
        return (expand(flat, self.terms) @ self.M.T).reshape(shape)

    def to_dict(self) -> dict:
        return {
            "kind": self.kind,
            "terms": list(self.terms),
            "coefficients": [[float(v) for v in row] for row in self.M],
            "white_preserving": bool(self.white_preserving),
            "objective": self.objective,
            "regularisation": float(self.regularisation),
        }

    def __eq__(self, other: object) -> bool:
        return type(other) is type(self) and self.to_dict() == other.to_dict()  # type: ignore[attr-defined]

    __hash__ = None  # type: ignore[assignment]


def _kernel(r: np.ndarray, kernel: str) -> np.ndarray:
    if kernel == "polyharmonic-1":
        return r
    if kernel == "polyharmonic-3":
        return r**3
    if kernel == "thin-plate":
        with np.errstate(divide="ignore", invalid="ignore"):
            out = r**2 * np.log(r)
        return np.where(r > 0, out, 0.0)
    raise CamcalError(f"unknown RBF kernel {kernel!r}, expected one of: {', '.join(RBF_KERNELS)}")


@dataclass(frozen=True, eq=False)
class RBFModel:
    """``XYZ = sum_j w_j phi(|RGB - c_j|) + L @ [R, G, B, 1]``.

    Attributes
    ----------
    kernel
        ``polyharmonic-1`` (phi = r), ``polyharmonic-3`` (r^3) or
        ``thin-plate`` (r^2 log r).
    centres
        ``(K, 3)`` linear camera RGB of the centres (the training patches).
    weights
        ``(K, 3)`` kernel weights, columns X, Y, Z.
    L
        ``(3, 4)`` linear part on the terms ``R, G, B, 1``.
    smoothing
        The ``lambda`` added to the kernel matrix diagonal in the fit.
    """

    kernel: str
    centres: np.ndarray
    weights: np.ndarray
    L: np.ndarray
    smoothing: float = 0.0
    objective: str = "xyz"

    kind = "rbf"
    linear_terms = ("R", "G", "B", "1")

    def __post_init__(self) -> None:
        for name in ("centres", "weights", "L"):
            value = np.array(getattr(self, name), dtype=np.float64)
            value.setflags(write=False)
            object.__setattr__(self, name, value)
        if self.kernel not in RBF_KERNELS:
            raise CamcalError(
                f"unknown RBF kernel {self.kernel!r}, expected one of: {', '.join(RBF_KERNELS)}"
            )
        K = self.centres.shape[0]
        if self.centres.shape != (K, 3) or self.weights.shape != (K, 3) or self.L.shape != (3, 4):
            raise CamcalError(
                "rbf model needs centres (K, 3), weights (K, 3) and a (3, 4) linear part, got "
                f"{self.centres.shape}, {self.weights.shape}, {self.L.shape}"
            )

    @property
    def label(self) -> str:
        return f"rbf:{self.kernel}"

    def apply(self, RGB: Any) -> np.ndarray:
        """Map linear camera RGB ``(..., 3)`` to XYZ ``(..., 3)``."""
        flat, shape = _as_rgb(RGB)
        r = np.linalg.norm(flat[:, None, :] - self.centres[None, :, :], axis=-1)
        out = _kernel(r, self.kernel) @ self.weights
        out = out + expand(flat, self.linear_terms) @ self.L.T
        return out.reshape(shape)

    def to_dict(self) -> dict:
        return {
            "kind": "rbf",
            "kernel": self.kernel,
            "smoothing": float(self.smoothing),
            "centres": [[float(v) for v in row] for row in self.centres],
            "weights": [[float(v) for v in row] for row in self.weights],
            "linear": {
                "terms": list(self.linear_terms),
                "coefficients": [[float(v) for v in row] for row in self.L],
            },
            "objective": self.objective,
        }

    def __eq__(self, other: object) -> bool:
        return type(other) is type(self) and self.to_dict() == other.to_dict()  # type: ignore[attr-defined]

    __hash__ = None  # type: ignore[assignment]


Model = LinearTermsModel | RBFModel


def model_from_dict(data: dict) -> Model:
    """Rebuild a model from its ``to_dict`` form (already schema-checked)."""
    kind = data["kind"]
    if kind == "rbf":
        linear = data["linear"]
        if list(linear["terms"]) != list(RBFModel.linear_terms):
            raise CamcalError("model.linear.terms: expected ['R', 'G', 'B', '1']")
        return RBFModel(
            kernel=data["kernel"],
            centres=np.array(data["centres"], dtype=np.float64).reshape(-1, 3),
            weights=np.array(data["weights"], dtype=np.float64).reshape(-1, 3),
            L=np.array(linear["coefficients"], dtype=np.float64),
            smoothing=float(data["smoothing"]),
            objective=data["objective"],
        )
    terms = tuple(data["terms"])
    for i, term in enumerate(terms):
        try:
            _, root = parse_term(term)
        except CamcalError as error:
            raise CamcalError(f"model.terms[{i}]: {error}") from None
        if root and kind != "root-polynomial":
            raise CamcalError(f"model.terms[{i}]: root term {term!r} in a {kind} model")
    if kind == "matrix3x3" and terms != ("R", "G", "B"):
        raise CamcalError("model.terms: a matrix3x3 model has the terms ['R', 'G', 'B']")
    return LinearTermsModel(
        kind=kind,
        terms=terms,
        M=np.array(data["coefficients"], dtype=np.float64),
        white_preserving=bool(data["white_preserving"]),
        objective=data["objective"],
        regularisation=float(data["regularisation"]),
    )


# --------------------------------------------------------------------------
# Fitting


def _check_training(RGB: Any, XYZ: Any, n_params: int, what: str) -> tuple[np.ndarray, np.ndarray]:
    RGB = np.asarray(RGB, dtype=np.float64)
    XYZ = np.asarray(XYZ, dtype=np.float64)
    if RGB.ndim != 2 or RGB.shape[1] != 3 or XYZ.shape != RGB.shape:
        raise CamcalError(
            f"training data must be RGB (N, 3) and XYZ (N, 3), got {RGB.shape} and {XYZ.shape}"
        )
    if not (np.all(np.isfinite(RGB)) and np.all(np.isfinite(XYZ))):
        raise CamcalError("training data contains NaN or infinite values")
    if RGB.shape[0] < n_params:
        raise CamcalError(
            f"{what} needs at least {n_params} patches, got {RGB.shape[0]}"
        )
    return RGB, XYZ


def _white_nullspace(r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Particular direction and null-space basis of the constraint ``r . m = w``."""
    r = r / np.linalg.norm(r)
    _, _, Vt = np.linalg.svd(r[None, :])
    return r, Vt[1:].T  # (T,), (T, T-1)


def fit_linear_terms(
    RGB: Any,
    XYZ: Any,
    terms: tuple[str, ...],
    *,
    kind: str,
    objective: str = "xyz",
    regularisation: float = 0.0,
    white_XYZ: Any = (0.9505, 1.0, 1.089),
    RGB_white: Any = None,
    max_nfev: int = 400,
) -> LinearTermsModel:
    """Fit ``XYZ = M @ expand(RGB, terms)``.

    Parameters
    ----------
    RGB, XYZ
        ``(N, 3)`` linear camera RGB and reference XYZ (white Y = 1).
    terms
        Canonical term strings.
    kind
        Model kind recorded in the result.
    objective
        ``"xyz"``: closed-form regularised least squares in XYZ;
        ``"de2000"``: minimise the sum of squared CIEDE2000, started from
        the ``"xyz"`` solution.
    regularisation
        Ridge ``lambda`` on the non-linear terms (see the module docstring).
    white_XYZ
        XYZ of the target white, for CIELAB in the ``de2000`` objective.
    RGB_white
        Camera RGB of the perfect white; when given, the fit is white
        preserving: ``M @ expand(RGB_white) = white_XYZ`` exactly.

    Returns
    -------
    LinearTermsModel
    """
    if objective not in OBJECTIVES:
        raise CamcalError(f"unknown objective {objective!r}, expected one of: xyz, de2000")
    terms = tuple(terms)
    T = len(terms)
    RGB, XYZ = _check_training(RGB, XYZ, T if regularisation == 0 else 3, kind)
    N = RGB.shape[0]
    A = expand(RGB, terms)
    penalty = _nonlinear_mask(terms).astype(np.float64) * float(regularisation)
    white_XYZ = np.asarray(white_XYZ, dtype=np.float64)

    if RGB_white is not None:
        r = expand(np.asarray(RGB_white, dtype=np.float64)[None, :], terms)[0]
        r_unit, Nb = _white_nullspace(r)
        norm_r = np.linalg.norm(r)
        M0 = np.outer(white_XYZ / norm_r, r_unit)  # (3, T): M0 @ r = white
        # M = M0 + Z @ Nb.T, Z (3, T-1)
        A_red = A @ Nb
        target = XYZ - A @ M0.T
        P = Nb.T @ np.diag(penalty) @ Nb
        Z = np.linalg.solve(A_red.T @ A_red / N + P + 1e-15 * np.eye(T - 1), A_red.T @ target / N).T
        M = M0 + Z @ Nb.T

        def unpack(p: np.ndarray) -> np.ndarray:
            return M0 + p.reshape(-1, 3, T - 1) @ Nb.T

        p0 = Z.ravel()
    else:
        ATA = A.T @ A / N + np.diag(penalty)
        M = np.linalg.lstsq(ATA, A.T @ XYZ / N, rcond=None)[0].T

        def unpack(p: np.ndarray) -> np.ndarray:
            return p.reshape(-1, 3, T)

        p0 = M.ravel()

    if objective == "de2000":
        M = _refine_de2000(A, XYZ, white_XYZ, unpack, p0, penalty, max_nfev)
    return LinearTermsModel(
        kind=kind,
        terms=terms,
        M=M,
        white_preserving=RGB_white is not None,
        objective=objective,
        regularisation=float(regularisation),
    )


def delta_E2000_components(Lab_1: np.ndarray, Lab_2: np.ndarray) -> np.ndarray:
    """Three residuals whose Euclidean norm is CIEDE2000 (for optimisers).

    CIEDE2000 is ``sqrt(u^2 + v^2 + w^2 + R_T v w)`` with
    ``u = dL'/S_L``, ``v = dC'/S_C``, ``w = dH'/S_H`` (*Sharma et al.
    2005*, k_L = k_C = k_H = 1). Completing the square gives the vector
    ``(u, v + R_T w / 2, w sqrt(1 - R_T^2 / 4))`` of the same norm, which
    is smooth where the scalar Delta E (a square root) is not: a least
    squares solver converges on it in a few Gauss-Newton steps. Reported
    figures always come from colour-science's ``delta_E``; a test checks
    that the norm of this vector equals it.

    Parameters
    ----------
    Lab_1, Lab_2
        ``(..., 3)`` CIELAB.

    Returns
    -------
    numpy.ndarray
        ``(..., 3)``.
    """
    L1, a1, b1 = np.moveaxis(np.asarray(Lab_1, dtype=np.float64), -1, 0)
    L2, a2, b2 = np.moveaxis(np.asarray(Lab_2, dtype=np.float64), -1, 0)
    C_bar = (np.hypot(a1, b1) + np.hypot(a2, b2)) / 2
    G = 0.5 * (1 - np.sqrt(C_bar**7 / (C_bar**7 + 25.0**7)))
    a1p, a2p = (1 + G) * a1, (1 + G) * a2
    C1p, C2p = np.hypot(a1p, b1), np.hypot(a2p, b2)
    h1p = np.degrees(np.arctan2(b1, a1p)) % 360
    h2p = np.degrees(np.arctan2(b2, a2p)) % 360
    zero = C1p * C2p == 0
    dh = h2p - h1p
    dh = np.where(dh > 180, dh - 360, np.where(dh < -180, dh + 360, dh))
    dh = np.where(zero, 0.0, dh)
    dLp = L2 - L1
    dCp = C2p - C1p
    dHp = 2 * np.sqrt(C1p * C2p) * np.sin(np.radians(dh) / 2)
    L_barp = (L1 + L2) / 2
    C_barp = (C1p + C2p) / 2
    h_sum = h1p + h2p
    h_barp = np.where(
        np.abs(h1p - h2p) <= 180, h_sum / 2, np.where(h_sum < 360, (h_sum + 360) / 2, (h_sum - 360) / 2)
    )
    h_barp = np.where(zero, h_sum, h_barp)
    T = (1 - 0.17 * np.cos(np.radians(h_barp - 30)) + 0.24 * np.cos(np.radians(2 * h_barp))
         + 0.32 * np.cos(np.radians(3 * h_barp + 6)) - 0.20 * np.cos(np.radians(4 * h_barp - 63)))
    d_theta = 30 * np.exp(-(((h_barp - 275) / 25) ** 2))
    R_C = 2 * np.sqrt(C_barp**7 / (C_barp**7 + 25.0**7))
    S_L = 1 + 0.015 * (L_barp - 50) ** 2 / np.sqrt(20 + (L_barp - 50) ** 2)
    S_C = 1 + 0.045 * C_barp
    S_H = 1 + 0.015 * C_barp * T
    R_T = -np.sin(np.radians(2 * d_theta)) * R_C
    u, v, w = dLp / S_L, dCp / S_C, dHp / S_H
    return np.stack([u, v + R_T * w / 2, w * np.sqrt(np.clip(1 - R_T**2 / 4, 0, None))], axis=-1)


def _refine_de2000(
    A: np.ndarray,
    XYZ: np.ndarray,
    white_XYZ: np.ndarray,
    unpack,
    p0: np.ndarray,
    penalty: np.ndarray,
    max_nfev: int,
) -> np.ndarray:
    """Minimise the sum of squared CIEDE2000 over the parameters ``p``.

    The residuals are :func:`delta_E2000_components` (3 per patch, their
    norm is the patch's CIEDE2000), with CIELAB from colour-science. The
    Jacobian is a forward difference computed in one batched evaluation.
    The ridge penalty is carried over with the ratio of squared CIEDE2000
    to squared XYZ residuals at the start, so ``lambda`` weighs the same in
    both objectives.
    """
    from scipy.optimize import least_squares

    from camcal.colour.evaluate import XYZ_to_Lab

    Lab_ref = XYZ_to_Lab(XYZ, white_XYZ)
    N = A.shape[0]

    def penalties(Ms: np.ndarray) -> np.ndarray:  # (B, 3, T) -> (B, 3*T)
        return (np.sqrt(penalty)[None, None, :] * Ms).reshape(Ms.shape[0], -1)

    def colour_residuals(Ms: np.ndarray) -> np.ndarray:  # (B, 3, T) -> (B, 3N)
        pred = np.einsum("nt,bkt->bnk", A, Ms)
        comp = delta_E2000_components(XYZ_to_Lab(pred, white_XYZ), Lab_ref[None])
        return comp.reshape(Ms.shape[0], -1)

    M_start = unpack(p0[None])
    scale = 0.0
    if np.any(penalty):
        xyz_sq = np.sum((A @ M_start[0].T - XYZ) ** 2)
        scale = np.sqrt(N * np.sum(colour_residuals(M_start) ** 2) / max(xyz_sq, 1e-300))

    def residuals_batch(P: np.ndarray) -> np.ndarray:
        Ms = unpack(P)
        return np.concatenate([colour_residuals(Ms), scale * penalties(Ms)], axis=1)

    def fun(p: np.ndarray) -> np.ndarray:
        return residuals_batch(p[None])[0]

    def jac(p: np.ndarray) -> np.ndarray:
        h = 1e-7 * np.maximum(1.0, np.abs(p))
        R = residuals_batch(np.vstack([p[None], p[None] + np.diag(h)]))
        return ((R[1:] - R[0][None]) / h[:, None]).T

    result = least_squares(fun, p0, jac=jac, method="trf", max_nfev=max_nfev, ftol=1e-8, xtol=1e-10)
    return unpack(result.x[None])[0]


def _rbf_system(RGB: np.ndarray, kernel: str, smoothing: float) -> np.ndarray:
    N = RGB.shape[0]
    r = np.linalg.norm(RGB[:, None, :] - RGB[None, :, :], axis=-1)
    Phi = _kernel(r, kernel) + smoothing * np.eye(N)
    P = np.hstack([RGB, np.ones((N, 1))])
    S = np.zeros((N + 4, N + 4))
    S[:N, :N] = Phi
    S[:N, N:] = P
    S[N:, :N] = P.T
    return S


def _rbf_solve(RGB: np.ndarray, XYZ: np.ndarray, kernel: str, smoothing: float):
    N = RGB.shape[0]
    S = _rbf_system(RGB, kernel, smoothing)
    rhs = np.vstack([XYZ, np.zeros((4, 3))])
    sol = np.linalg.lstsq(S, rhs, rcond=None)[0]
    return sol[:N], sol[N:].T  # weights (N, 3), L (3, 4)


def _rbf_loo_predictions(RGB: np.ndarray, XYZ: np.ndarray, kernel: str, smoothing: float) -> np.ndarray:
    """Exact leave-one-out predictions of a smoothing RBF (a linear smoother).

    With ``H`` the hat matrix (fitted = H XYZ), the leave-one-out residual is
    ``e_i / (1 - H_ii)``; valid for ``smoothing > 0``.
    """
    N = RGB.shape[0]
    S = _rbf_system(RGB, kernel, smoothing)
    rhs = np.vstack([np.eye(N), np.zeros((4, N))])
    sol = np.linalg.lstsq(S, rhs, rcond=None)[0]
    Phi0 = _kernel(np.linalg.norm(RGB[:, None, :] - RGB[None, :, :], axis=-1), kernel)
    P = np.hstack([RGB, np.ones((N, 1))])
    H = Phi0 @ sol[:N] + P @ sol[N:]
    fitted = H @ XYZ
    leverage = np.clip(1.0 - np.diag(H), 1e-9, None)
    return XYZ - (XYZ - fitted) / leverage[:, None]


RBF_SMOOTHING_GRID = tuple(float(v) for v in np.logspace(-7, 0, 15))


def fit_rbf(
    RGB: Any,
    XYZ: Any,
    *,
    kernel: str = "polyharmonic-1",
    smoothing: float | None = None,
    white_XYZ: Any = (0.9505, 1.0, 1.089),
    objective: str = "xyz",
) -> RBFModel:
    """Fit a polyharmonic RBF network with a linear part (*Thomas 2011*).

    Parameters
    ----------
    RGB, XYZ
        ``(N, 3)`` training data; the centres are the training RGB.
    kernel
        One of :data:`RBF_KERNELS`.
    smoothing
        ``lambda`` added to the kernel diagonal; ``None`` chooses it from
        :data:`RBF_SMOOTHING_GRID` by exact leave-one-out mean CIEDE2000.
    white_XYZ
        Target white, for CIELAB when choosing ``smoothing``.

    Returns
    -------
    RBFModel
    """
    if objective != "xyz":
        raise CamcalError("objective de2000 is not available for rbf models, use xyz")
    RGB, XYZ = _check_training(RGB, XYZ, 5, "rbf")
    if kernel not in RBF_KERNELS:
        raise CamcalError(f"unknown RBF kernel {kernel!r}, expected one of: {', '.join(RBF_KERNELS)}")
    if smoothing is None:
        from camcal.colour.evaluate import delta_E

        best = None
        for lam in RBF_SMOOTHING_GRID:
            pred = _rbf_loo_predictions(RGB, XYZ, kernel, lam)
            score = float(np.mean(delta_E(pred, XYZ, white_XYZ)))
            if best is None or score < best[0]:
                best = (score, lam)
        smoothing = best[1]
    weights, L = _rbf_solve(RGB, XYZ, kernel, float(smoothing))
    return RBFModel(kernel=kernel, centres=RGB, weights=weights, L=L, smoothing=float(smoothing))


def fit_model(
    spec: ModelSpec | str,
    RGB: Any,
    XYZ: Any,
    *,
    objective: str = "xyz",
    regularisation: float = 0.0,
    white_XYZ: Any = (0.9505, 1.0, 1.089),
    RGB_white: Any = None,
    smoothing: float | None = None,
) -> Model:
    """Fit the model ``spec`` to training patches (the one dispatcher).

    Parameters
    ----------
    spec
        A :class:`ModelSpec` or its string (``"root-polynomial:2"``...).
    RGB, XYZ
        ``(N, 3)`` linear camera RGB and reference XYZ, white Y = 1.
    objective
        ``"xyz"`` or ``"de2000"`` (linear-terms models only).
    regularisation
        Ridge ``lambda`` for the non-linear terms.
    white_XYZ
        XYZ of the target white.
    RGB_white
        Camera RGB of the perfect white; required when ``spec`` is white
        preserving, ignored otherwise.
    smoothing
        RBF smoothing; ``None`` picks it by leave-one-out.

    Returns
    -------
    LinearTermsModel or RBFModel
    """
    if isinstance(spec, str):
        spec = parse_model_spec(spec)
    if spec.kind == "rbf":
        return fit_rbf(RGB, XYZ, kernel=spec.kernel, smoothing=smoothing,
                       white_XYZ=white_XYZ, objective=objective)
    if spec.white_preserving and RGB_white is None:
        raise CamcalError(
            f"{spec.label} needs the camera RGB of the white (no neutral patches given)"
        )
    return fit_linear_terms(
        RGB,
        XYZ,
        spec.terms(),
        kind=spec.kind,
        objective=objective,
        regularisation=regularisation,
        white_XYZ=white_XYZ,
        RGB_white=RGB_white if spec.white_preserving else None,
    )
