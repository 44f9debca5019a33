"""Baking a colour function into OpenColorIO transforms: exact matrix, or log-chromaticity shaper + Lut3D.

:func:`transform_from_callable` turns any ``apply(RGB (N, 3)) -> (N, 3)``
(linear RGB to linear RGB, or to XYZ) into OCIO transforms: an exact
``MatrixTransform`` when a 3x3 matrix is given, otherwise a log2 shaper and
a matrix to log-chromaticity coordinates (:class:`LogChromaticity`), a
tetrahedral ``Lut3D``, an inverse log2 shaper and a 3x3 matrix, whose
CIEDE2000 bake error is measured over sample points
(:mod:`camcal.colour.bake.samples` says where). The OCIO export, the ICC
export and ``--model auto``'s exportability check share it.

PyOpenColorIO is imported only through :func:`ocio_module` (lazily, with the
one line naming the extra when it is missing).

References
----------
- SMPTE ST 2136-1 / Academy S-2014-006: Common LUT Format (CLF).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from camcal.base.errors import CamcalError
from camcal.base.extras import require
from camcal.colour.difference import DeltaEStats, delta_E

__all__ = [
    "CLF_FORMAT",
    "LUT_SIZES",
    "ocio_module",
    "LogShaper",
    "BAKE_SHAPER",
    "LogChromaticity",
    "BakedTransform",
    "matrix_transform",
    "cpu_processor",
    "apply_cpu",
    "transform_from_callable",
]

CLF_FORMAT = "Academy/ASC Common LUT Format"
LUT_SIZES = (17, 33, 49, 65, 81, 97)
# The samples are a finite set: a size whose error on them is within this share of the allowed error leaves the
# rest for colours between them (the demo's right camera: 0.142 on the samples, 0.2008 on 190 independent
# reflectances at the first size that met 0.2); else the most accurate size within the allowed error.
SAMPLE_MARGIN = 0.5


def ocio_module():
    """The ``PyOpenColorIO`` module (the one line naming the ``colour`` extra when it is missing)."""
    return require("PyOpenColorIO")


# The shaper and the baking of a callable.


@dataclass(frozen=True)
class LogShaper:
    """A per-channel log2 shaper with a linear toe, OCIO's ``LogCameraTransform``.

    ``s(x) = (log2(x) - low_stop) / (high_stop - low_stop)`` for
    ``x >= 2**break_stop``; below the break, the tangent line (C1
    continuous), so zero and small negative values stay inside [0, 1].
    ``s = 1`` at ``x = 2**high_stop``. In a CLF file it is a ``Log`` node of
    style ``cameraLinToLog``.

    Attributes
    ----------
    low_stop, high_stop, break_stop
        In stops (log2) of linear value; ``low_stop < break_stop < high_stop``.
    """

    low_stop: float = -8.0
    high_stop: float = 3.0
    break_stop: float = -6.0

    def __post_init__(self) -> None:
        if not (self.low_stop < self.break_stop < self.high_stop):
            raise CamcalError(
                f"shaper stops must satisfy low < break < high, got {self.low_stop}, {self.break_stop}, "
                f"{self.high_stop}"
            )

    @property
    def _span(self) -> float:
        return self.high_stop - self.low_stop

    def params(self) -> dict:
        """Keyword arguments of ``PyOpenColorIO.LogCameraTransform``."""
        span = self._span
        return dict(base=2.0, logSideSlope=[1.0 / span] * 3, logSideOffset=[-self.low_stop / span] * 3,
                    linSideSlope=[1.0] * 3, linSideOffset=[0.0] * 3, linSideBreak=[2.0**self.break_stop] * 3)

    def transform(self, inverse: bool = False):
        """The OCIO transform (``inverse``: shaped values back to linear)."""
        ocio = ocio_module()
        direction = ocio.TRANSFORM_DIR_INVERSE if inverse else ocio.TRANSFORM_DIR_FORWARD
        return ocio.LogCameraTransform(**self.params(), direction=direction)

    def encode(self, x: Any) -> np.ndarray:
        """``s(x)`` in numpy (any shape)."""
        x = np.asarray(x, dtype=np.float64)
        b = 2.0**self.break_stop
        s_b = (self.break_stop - self.low_stop) / self._span
        slope = 1.0 / (self._span * b * math.log(2.0))
        with np.errstate(divide="ignore", invalid="ignore"):
            log = (np.log2(np.maximum(x, b)) - self.low_stop) / self._span
        return np.where(x >= b, log, s_b + slope * (x - b))

    def decode(self, s: Any) -> np.ndarray:
        """``s^-1`` in numpy (any shape)."""
        s = np.asarray(s, dtype=np.float64)
        b = 2.0**self.break_stop
        s_b = (self.break_stop - self.low_stop) / self._span
        slope = 1.0 / (self._span * b * math.log(2.0))
        exp = 2.0 ** (np.maximum(s, s_b) * self._span + self.low_stop)
        return np.where(s >= s_b, exp, b + (s - s_b) / slope)

    @property
    def domain(self) -> tuple[float, float]:
        """Linear values mapped to 0 and 1 (a Lut3D clamps outside them)."""
        return float(self.decode(0.0)), float(self.decode(1.0))


def _matrix44(M: Any, offset: Any = (0.0, 0.0, 0.0)) -> tuple[list[float], list[float]]:
    M = np.asarray(M, dtype=np.float64)
    m44 = np.eye(4)
    m44[:3, :3] = M
    return [float(v) for v in m44.ravel()], [float(v) for v in offset] + [0.0]


def matrix_transform(M: Any, offset: Any = (0.0, 0.0, 0.0)):
    """An OCIO ``MatrixTransform`` of a 3x3 matrix and an offset."""
    ocio = ocio_module()
    m44, off = _matrix44(M, offset)
    return ocio.MatrixTransform(m44, off)


def cpu_processor(transform, config=None):
    """The default OCIO CPU processor of a transform (in a raw config unless one is given)."""
    ocio = ocio_module()
    config = config if config is not None else ocio.Config.CreateRaw()
    return config.getProcessor(transform).getDefaultCPUProcessor()


def apply_cpu(cpu, RGB: np.ndarray) -> np.ndarray:
    """Apply an OCIO CPU processor to ``(..., 3)`` values: ``(N, 3)`` float64 (OCIO computes in float32)."""
    pixels = np.ascontiguousarray(np.asarray(RGB, dtype=np.float32).reshape(-1, 3))
    cpu.applyRGB(pixels)
    return pixels.astype(np.float64)


BAKE_SHAPER = LogShaper(low_stop=-14.0, high_stop=3.0, break_stop=-10.0)


@dataclass(frozen=True, eq=False)
class LogChromaticity:
    """Input coordinates of a baked Lut3D: log2 luminance and two log2 chromaticity ratios.

    ``u = A s(x) + a`` with ``s`` the per-channel :class:`LogShaper` of the
    linear input ``x``; the rows of ``A`` are ``(1, 1, 1) / 3`` (mean
    shaped value: log exposure), ``(1, -1, 0) / w_1`` and ``(0, -1, 1) / w_2``
    (``log2(R / G)`` and ``log2(B / G)`` above the toe, scaled so that the
    chromaticities of the samples, widened by a margin, fill [0, 1]).

    Attributes
    ----------
    shaper
        The per-channel shaper.
    matrix, offset
        ``A`` ``(3, 3)`` and ``a`` ``(3,)``.

    Notes
    -----
    Exposure moves a colour along the first axis only. An
    exposure-invariant model (root-polynomial, ``f(k x) = k f(x)``) whose
    output is log-shaped the same way is then linear along that axis, so the
    Lut3D's grid only has to follow the model across chromaticity, and the
    chromaticity axes are spent on the range real colours occupy instead of
    the whole cube of per-channel values.
    """

    shaper: LogShaper
    matrix: np.ndarray
    offset: np.ndarray

    @classmethod
    def from_samples(cls, samples: Any, shaper: LogShaper = BAKE_SHAPER, margin: float = 0.1,
                     min_half_width: float = 1.0) -> LogChromaticity:
        """Coordinates whose chromaticity axes span ``samples`` (``(N, 3)`` linear RGB).

        Each log2 chromaticity range is widened by ``margin`` of its width on
        both sides and to at least ``min_half_width`` stops around its middle.
        The samples are the fit's preimages of the chart and of plausible
        surfaces, not the patches the camera recorded: a camera that renders
        more saturated than its fit (the real sRGB ColorChecker photo of the
        tests: its yellow-green patch at -0.013 on the blue axis with a margin
        of 0.05, clamped by the Lut3D, CIEDE2000 0.75 off the fit) needs the
        wider margin (0.1: 0.035, at the same 33^3 size).
        """
        D = np.array([[1 / 3, 1 / 3, 1 / 3], [1.0, -1.0, 0.0], [0.0, -1.0, 1.0]])
        c = shaper.encode(np.maximum(np.asarray(samples, dtype=np.float64).reshape(-1, 3), 0.0)) @ D.T
        low, high = c.min(axis=0), c.max(axis=0)
        half = np.maximum((high - low) * (0.5 + margin), min_half_width / (shaper.high_stop - shaper.low_stop))
        middle = (low + high) / 2
        low, high = middle - half, middle + half
        low[0], high[0] = 0.0, 1.0
        return cls(shaper, np.diag(1.0 / (high - low)) @ D, -low / (high - low))

    @classmethod
    def per_channel(cls, shaper: LogShaper = LogShaper()) -> LogChromaticity:
        """Plain per-channel shaped coordinates (``A`` the identity): for functions with kinks in RGB."""
        return cls(shaper, np.eye(3), np.zeros(3))

    def encode(self, x: Any) -> np.ndarray:
        """Linear ``(N, 3)`` to coordinates ``u`` (in [0, 1] inside the domain)."""
        return self.shaper.encode(x) @ self.matrix.T + self.offset

    def decode(self, u: Any) -> np.ndarray:
        """Coordinates ``u`` to linear values (``encode``'s inverse)."""
        return self.shaper.decode((np.asarray(u, dtype=np.float64) - self.offset) @ np.linalg.inv(self.matrix).T)

    def transforms(self) -> list:
        """OCIO transforms: ``LogCameraTransform`` then ``MatrixTransform``."""
        return [self.shaper.transform(), matrix_transform(self.matrix, self.offset)]


@dataclass(frozen=True, eq=False)
class BakedTransform:
    """An RGB -> RGB (or XYZ) function as OCIO transforms.

    Attributes
    ----------
    kind
        ``"matrix"`` (exact) or ``"lut3d"`` (baked).
    transform
        A ``PyOpenColorIO.GroupTransform``: one ``MatrixTransform``, or
        ``[log shaper, MatrixTransform(A, a), Lut3D, inverse log shaper,
        MatrixTransform(M)]`` (see :func:`transform_from_callable`).
    matrix
        ``(3, 3)``: the exact matrix, or the least-squares linear part that
        the Lut3D's output is expressed in.
    lut_size
        Lut3D edge length, ``None`` for a matrix.
    shaper
        The output :class:`LogShaper` (``None`` for a matrix).
    bake_error
        CIEDE2000 between the OCIO processor and the function over the
        sample points (``None`` for a matrix, which is exact).
    coordinates
        The Lut3D's input :class:`LogChromaticity` (``None`` for a matrix).
    table
        ``(n, n, n, 3)`` float32 Lut3D values, first input axis slowest
        (``None`` for a matrix); the ICC exporter writes the same table.
    """

    kind: str
    transform: Any
    matrix: np.ndarray
    lut_size: int | None = None
    shaper: LogShaper | None = None
    bake_error: DeltaEStats | None = None
    coordinates: LogChromaticity | None = None
    table: np.ndarray | None = None

    def clf_text(self, identifier: str, description: str = "") -> str:
        """The transform as CLF (SMPTE ST 2136-1) text, written by OCIO's own writer."""
        ocio = ocio_module()
        group = ocio.GroupTransform([t for t in self.transform])
        metadata = group.getFormatMetadata()
        metadata.setID(identifier)
        if description:
            metadata.addChildElement("Description", description)
        return group.write(CLF_FORMAT, ocio.Config.CreateRaw())


def _lut3d_table(apply: Callable, n: int, coordinates: LogChromaticity, shaper: LogShaper,
                 M: np.ndarray) -> np.ndarray:
    """``s(M^-1 apply(x))`` at the grid nodes, ``x`` the decoded node clipped to the input shaper's domain."""
    g = np.linspace(0.0, 1.0, n)
    grid = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)  # first axis slowest
    x = np.clip(coordinates.decode(grid), *coordinates.shaper.domain)
    y = np.asarray(apply(x), dtype=np.float64).reshape(-1, 3) @ np.linalg.inv(M).T
    table = shaper.encode(y)
    if not np.all(np.isfinite(table)):
        raise CamcalError("the function gave non-finite values inside the Lut3D's domain; cannot bake it")
    return table.astype(np.float32).reshape(n, n, n, 3)


def _lut3d_group(table: np.ndarray, coordinates: LogChromaticity, shaper: LogShaper, M: np.ndarray):
    ocio = ocio_module()
    n = table.shape[0]
    lut = ocio.Lut3DTransform(n)
    lut.setInterpolation(ocio.INTERP_TETRAHEDRAL)
    lut.setData(np.ascontiguousarray(table, dtype=np.float32).ravel())
    return ocio.GroupTransform([*coordinates.transforms(), lut, shaper.transform(inverse=True),
                                matrix_transform(M)])


def transform_from_callable(
    apply: Callable[[np.ndarray], np.ndarray],
    *,
    matrix: Any = None,
    samples: Any = None,
    white_XYZ: Any = None,
    to_XYZ: Callable[[np.ndarray], np.ndarray] | None = None,
    max_delta_E: float = 0.2,
    lut_sizes: Sequence[int] = LUT_SIZES,
    shaper: LogShaper = BAKE_SHAPER,
) -> BakedTransform:
    """Turn a linear-RGB function into OCIO transforms: exact matrix or log-chromaticity Lut3D.

    Parameters
    ----------
    apply
        ``apply(RGB (N, 3)) -> (N, 3)``: linear RGB to linear RGB (e.g. a
        camera-to-camera match) or to XYZ (a characterisation).
    matrix
        ``(3, 3)``: when given, ``apply`` IS this matrix and the result is an
        exact ``MatrixTransform`` (``samples`` etc. are not needed).
    samples
        ``(N, 3)`` inputs where accuracy matters (e.g. :func:`bake_samples`:
        the chart gamut and plausible surface colours); they set the Lut3D's
        chromaticity range and the bake error is measured there.
    white_XYZ
        White for CIELAB/CIEDE2000 of the outputs (after ``to_XYZ``).
    to_XYZ
        Maps the function's outputs to XYZ for measuring the error (for an
        RGB -> RGB function: e.g. camera A's characterisation); ``None`` when
        the outputs are XYZ.
    max_delta_E
        Largest CIEDE2000 allowed between the baked transform and ``apply``
        over ``samples``; the smallest size of ``lut_sizes`` within
        :data:`SAMPLE_MARGIN` of it is used, else the most accurate size that
        meets it.
    lut_sizes
        Lut3D edge lengths to try, ascending (OCIO allows up to 129).
    shaper
        Per-channel log2 shaper of the input coordinates and of the output
        (default :data:`BAKE_SHAPER`: linear values up to 8; above, the
        input clamps).

    Returns
    -------
    BakedTransform

    Raises
    ------
    CamcalError
        No size meets ``max_delta_E`` (the message gives the error reached),
        missing samples/white, or a non-finite function.

    Notes
    -----
    The Lut3D is indexed by :class:`LogChromaticity` coordinates
    ``u = A s(x) + a`` (log exposure and two log2 chromaticity ratios, the
    ratios' range set by ``samples``) and stores ``s(M^-1 apply(x))``, with
    ``M`` the least-squares matrix of ``apply`` over ``samples``; it is
    followed by ``s^-1`` and ``M``. For a root-polynomial fit the stored
    function is linear along the exposure axis, so the grid only follows its
    curvature across chromaticity. At each size, plain per-channel log2
    coordinates (:meth:`LogChromaticity.per_channel`, input and output
    shaped by the default :class:`LogShaper`, -8 to +3 stops) are tried when
    the log-chromaticity ones miss ``max_delta_E`` (a piecewise-linear
    function in RGB, such as a Lut3D match, bakes better on its own axes).
    Interpolation is tetrahedral. Grid nodes
    that decode outside ``[0, 2**high_stop]`` (outside any real colour) are
    evaluated at the clipped value.

    Examples
    --------
    >>> M = np.array([[0.6, 0.3, 0.1], [0.2, 0.7, 0.1], [0.0, 0.1, 0.9]])
    >>> transform_from_callable(lambda x: x @ M.T, matrix=M).kind
    'matrix'
    """
    if matrix is not None:
        M = np.asarray(matrix, dtype=np.float64)
        if M.shape != (3, 3) or not np.all(np.isfinite(M)):
            raise CamcalError(f"matrix must be a finite 3x3 array, got shape {M.shape}")
        return BakedTransform("matrix", ocio_module().GroupTransform([matrix_transform(M)]), M)
    if samples is None or white_XYZ is None:
        raise CamcalError("baking a non-linear function needs sample points and a white for Delta E")
    X = np.asarray(samples, dtype=np.float64).reshape(-1, 3)
    if X.shape[0] < 4 or not np.all(np.isfinite(X)):
        raise CamcalError(f"need at least 4 finite sample points (N, 3), got {X.shape}")
    sizes = sorted(int(n) for n in lut_sizes)
    if not sizes or sizes[0] < 2 or sizes[-1] > 129:
        raise CamcalError(f"Lut3D sizes must lie in 2..129, got {list(lut_sizes)}")
    to_XYZ = to_XYZ or (lambda values: values)
    Y = np.asarray(apply(X), dtype=np.float64)
    M = np.linalg.lstsq(X, Y, rcond=None)[0].T
    if not np.all(np.isfinite(M)) or np.linalg.cond(M) > 1e8:
        M = np.eye(3)
    reference = to_XYZ(Y)
    error, best = None, None
    for n in sizes:
        for coordinates, out in ((LogChromaticity.from_samples(X, shaper), shaper),
                                 (LogChromaticity.per_channel(), LogShaper())):
            table = _lut3d_table(apply, n, coordinates, out, M)
            group = _lut3d_group(table, coordinates, out, M)
            baked = apply_cpu(cpu_processor(group), X)
            found = DeltaEStats.from_values(delta_E(to_XYZ(baked), reference, white_XYZ))
            if found.max <= SAMPLE_MARGIN * max_delta_E:
                return BakedTransform("lut3d", group, M, n, out, found, coordinates, table)
            if found.max <= max_delta_E and (best is None or found.max < best.bake_error.max):
                best = BakedTransform("lut3d", group, M, n, out, found, coordinates, table)
            error = found if error is None or found.max < error.max else error
    if best is not None:
        return best
    raise CamcalError(
        f"a {sizes[-1]}^3 Lut3D still leaves CIEDE2000 up to {error.max:.3f} over the samples "
        f"(allowed {max_delta_E:g}); allow a larger bake error or refit with a smoother model"
    )
