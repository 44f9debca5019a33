"""Characterisation models: linear camera RGB to CIE XYZ.

Four model kinds, each a frozen dataclass with ``apply(RGB) -> XYZ``,
``to_dict()`` / ``from_dict()`` (the ``model`` block of ``*.colour.json``)
and a fitting function behind one dispatcher,
:func:`camcal.colour.fit.fitting.fit_model` (term sets and names:
:mod:`camcal.colour.fit.terms`):

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
- Terms are strings, written and expanded as :mod:`camcal.colour.fit.terms`
  describes (polynomial and sign-preserving root terms).

The objectives and the regularisation are those of the fit dispatcher,
:func:`camcal.colour.fit.fitting.fit_model`.

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

from dataclasses import dataclass
from typing import Any

import numpy as np

from camcal.base.errors import CamcalError
from camcal.colour.fit.terms import RBF_KERNELS, expand, parse_term

__all__ = ["Model", "LinearTermsModel", "RBFModel", "model_from_dict", "as_rgb", "rbf_kernel"]


def as_rgb(RGB: Any) -> tuple[np.ndarray, tuple[int, ...]]:
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
    shrinkage
        Weight of the ``matrix3x3`` fit blended in (recorded in the file when
        not 0; :func:`camcal.colour.fit.fitting.fit_linear_terms`).
    """

    kind: str
    terms: tuple[str, ...]
    M: np.ndarray
    white_preserving: bool = False
    objective: str = "xyz"
    regularisation: float = 0.0
    shrinkage: float = 0.0

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
        flat, shape = as_rgb(RGB)
        return (expand(flat, self.terms) @ self.M.T).reshape(shape)

    def to_dict(self) -> dict:
        return {
            "kind": self.kind,
            "terms": list(self.terms),
            "coefficients": [[float(v) for v in row] for row in self.M],
            "white_preserving": bool(self.white_preserving),
            "objective": self.objective,
            "regularisation": float(self.regularisation),
        } | ({"shrinkage": float(self.shrinkage)} if self.shrinkage else {})

    def __eq__(self, other: object) -> bool:
        return type(other) is type(self) and self.to_dict() == other.to_dict()  # type: ignore[attr-defined]

    __hash__ = None  # type: ignore[assignment]


def rbf_kernel(r: np.ndarray, kernel: str) -> np.ndarray:
    """The radial basis function ``phi(r)`` of an RBF kernel name (:data:`RBF_KERNELS`)."""
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
        flat, shape = as_rgb(RGB)
        r = np.linalg.norm(flat[:, None, :] - self.centres[None, :, :], axis=-1)
        out = rbf_kernel(r, self.kernel) @ self.weights
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
        shrinkage=float(data.get("shrinkage", 0.0)),
    )


# --------------------------------------------------------------------------
