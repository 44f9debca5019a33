"""OpenColorIO export: colour fits as input colour spaces, CLF files and Looks.

A characterisation (``*.colour.json``) becomes one input colour space of an
OCIO config, named ``camcal <camera>`` in the family ``Input/camcal``
(the name the Blender add-on looks for), encoding ``scene-linear``, its
description carrying the fit's held-out CIEDE2000. Its transform to the
config's scene reference is, in order:

1. the linearisation (code values in [0, 1] to linear camera RGB):
   ``gamma-offset`` curves exactly as ``MatrixTransform`` (offset),
   ``ExponentTransform`` (negative values clamp to 0) and a diagonal
   ``MatrixTransform`` (gain); ``lut1d`` curves as a ``Lut1DTransform`` with
   the fit's own samples; ``named`` curves sampled into a 4096-entry
   ``Lut1DTransform`` (the largest relative error is reported). OCIO clamps
   a ``Lut1DTransform``'s input to [0, 1], the range of code values.
2. the model (linear camera RGB to XYZ under the fit's target white): a
   ``matrix3x3`` fit exactly as a ``MatrixTransform``; any other model as a
   ``FileTransform`` to a CLF file written by OCIO's own writer, holding a
   log2 shaper and a matrix to log-chromaticity coordinates
   (:class:`LogChromaticity`), a tetrahedral ``Lut3D`` and an inverse log2
   shaper followed by a 3x3 matrix (see :func:`transform_from_callable`),
   checked within CIEDE2000 0.2 over the chart gamut and plausible surface
   colours (:func:`bake_model`, the check ``--model auto`` uses too).
3. XYZ (target white) to the reference: chromatic adaptation from the
   target white to the ACES white (von Kries with Bradford, as OCIO's ACES
   configs do, or CAT02), the ACES2065-1 ``XYZ -> AP0`` matrix, then the
   base config's ``aces_interchange`` space to its scene reference (an
   identity for the ACES configs and camcal's base; a matrix for Blender's
   config, whose reference is CIE XYZ E).

The building blocks are generic so that other fits (the camera-to-camera
match, ``kind: match``) plug in:

- :func:`transform_from_callable` turns any ``apply(RGB (N, 3)) -> (N, 3)``
  (linear RGB to linear RGB, or to XYZ) into OCIO transforms: an exact
  ``MatrixTransform`` when a 3x3 matrix is given, otherwise a baked shaper +
  Lut3D whose CIEDE2000 bake error is measured over sample points.
- :class:`ColourSpaceSpec`, :class:`LookSpec`, :class:`ConfigSpec` describe
  a config; :func:`build_ocio_config` builds and validates it;
  :func:`write_ocio_config` writes it with its CLF files; :func:`add_look`
  adds a Look to a config.

PyOpenColorIO is imported only in this module (lazily, with a clear error).

References
----------
- Academy of Motion Picture Arts and Sciences (2014). TB-2014-004:
  Informative Notes on SMPTE ST 2065-1 - ACES (AP0 primaries, white).
- SMPTE ST 2136-1 / Academy S-2014-006: Common LUT Format (CLF).
- Lam, K. M. (1985). Metamerism and colour constancy (Bradford CAT).
"""

from __future__ import annotations

import math
import os
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from camcal import resources
from camcal.colour.evaluate import DeltaEStats, delta_E
from camcal.colour.fitfile import ColourFit
from camcal.colour.linearise import Linearisation
from camcal.base.errors import CamcalError
from camcal.base.atomic import atomic_write_text

__all__ = [
    "STUDIO_CONFIG",
    "CAMCAL_BASE",
    "FAMILY",
    "CLF_FORMAT",
    "LUT_SIZES",
    "CATS",
    "colour_space_name",
    "base_config_path",
    "load_base_config",
    "LogShaper",
    "BakedTransform",
    "transform_from_callable",
    "apply_cpu",
    "look_name",
    "look_from_match",
    "linearisation_transforms",
    "XYZ_to_reference_matrix",
    "invert_model",
    "chart_gamut_samples",
    "SURFACE_REFLECTANCES",
    "plausible_surface_XYZ",
    "plausible_surface_samples",
    "bake_samples",
    "bake_model",
    "bake_fit",
    "BAKE_SHAPER",
    "LogChromaticity",
    "ColourSpaceSpec",
    "LookSpec",
    "ConfigSpec",
    "add_look",
    "build_ocio_config",
    "write_ocio_config",
    "SpaceExport",
    "OCIOExport",
    "colour_space_from_fit",
    "export_ocio",
    "OUTPUT_SPACES",
    "output_matrix",
    "FitProcessor",
    "fit_processor",
]

STUDIO_CONFIG = "ocio://studio-config-latest"
CAMCAL_BASE = "camcal"
FAMILY = "Input/camcal"
CLF_FORMAT = "Academy/ASC Common LUT Format"
LUT_SIZES = (17, 33, 49, 65, 81, 97)
CATS = ("Bradford", "CAT02")
CURVE_SAMPLES = 4096
LUT_DIR = "luts"


def _ocio():
    try:
        import PyOpenColorIO as ocio
    except ImportError as error:  # pragma: no cover - opencolorio is a dependency
        raise CamcalError(f"OpenColorIO's Python module is not available ({error}); pip install opencolorio") from None
    return ocio


def colour_space_name(camera: str) -> str:
    """The colour space name of a camera: ``camcal <camera>`` (what the Blender add-on expects).

    Examples
    --------
    >>> colour_space_name("A7S-left")
    'camcal A7S-left'
    """
    return f"camcal {camera}"


def _slug(text: str) -> str:
    return re.sub(r"[^A-Za-z0-9._-]+", "_", text).strip("_") or "camera"


def base_config_path() -> Path:
    """camcal's base config template, ``camcal_base.ocio`` of :func:`camcal.resources.ocio_configs_dir`.

    ``CAMCAL_OCIO_CONFIGS`` overrides the folder.
    """
    override = os.environ.get("CAMCAL_OCIO_CONFIGS")
    folder = Path(override) if override else resources.ocio_configs_dir()
    path = folder / "camcal_base.ocio"
    if not path.is_file():
        raise CamcalError(f"camcal's base OCIO config was not found at {path} (set CAMCAL_OCIO_CONFIGS)")
    return path


def load_base_config(base: str | os.PathLike = STUDIO_CONFIG):
    """Load a base config: ``"camcal"``, an ``ocio://`` built-in name or a ``.ocio`` file.

    Returns
    -------
    PyOpenColorIO.Config
        A new (editable) config.

    Raises
    ------
    CamcalError
        Unknown built-in, missing or unreadable file.
    """
    ocio = _ocio()
    text = str(base)
    if text == CAMCAL_BASE:
        text = str(base_config_path())
    elif not text.startswith("ocio://") and not Path(text).is_file():
        raise CamcalError(f"base OCIO config not found: {text} (give 'camcal', ocio://NAME or a .ocio file)")
    try:
        return ocio.Config.CreateFromFile(text)
    except ocio.Exception as error:
        raise CamcalError(f"cannot load the base OCIO config {text}: {error}") from None


# --------------------------------------------------------------------------
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
        ocio = _ocio()
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


def _matrix_transform(M: Any, offset: Any = (0.0, 0.0, 0.0)):
    ocio = _ocio()
    m44, off = _matrix44(M, offset)
    return ocio.MatrixTransform(m44, off)


def _cpu(transform, config=None):
    ocio = _ocio()
    config = config if config is not None else ocio.Config.CreateRaw()
    return config.getProcessor(transform).getDefaultCPUProcessor()


def apply_cpu(cpu, RGB: np.ndarray) -> np.ndarray:
    """Apply an OCIO CPU processor to ``(..., 3)`` values: ``(N, 3)`` float64 (OCIO computes in float32)."""
    pixels = np.ascontiguousarray(np.asarray(RGB, dtype=np.float32).reshape(-1, 3))
    cpu.applyRGB(pixels)
    return pixels.astype(np.float64)


#: The per-channel log2 shaper of baked Lut3Ds: 17 stops (2**-14 to 8), a linear toe below 2**-10.
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
    def from_samples(cls, samples: Any, shaper: LogShaper = BAKE_SHAPER, margin: float = 0.05,
                     min_half_width: float = 1.0) -> LogChromaticity:
        """Coordinates whose chromaticity axes span ``samples`` (``(N, 3)`` linear RGB).

        Each log2 chromaticity range is widened by ``margin`` of its width on
        both sides and to at least ``min_half_width`` stops around its middle.
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
        return [self.shaper.transform(), _matrix_transform(self.matrix, self.offset)]


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
        ocio = _ocio()
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
    ocio = _ocio()
    n = table.shape[0]
    lut = ocio.Lut3DTransform(n)
    lut.setInterpolation(ocio.INTERP_TETRAHEDRAL)
    lut.setData(np.ascontiguousarray(table, dtype=np.float32).ravel())
    return ocio.GroupTransform([*coordinates.transforms(), lut, shaper.transform(inverse=True),
                                _matrix_transform(M)])


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
        over ``samples``; the smallest size of ``lut_sizes`` that meets it
        is used.
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
        return BakedTransform("matrix", _ocio().GroupTransform([_matrix_transform(M)]), M)
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
    error = None
    for n in sizes:
        for coordinates, out in ((LogChromaticity.from_samples(X, shaper), shaper),
                                 (LogChromaticity.per_channel(), LogShaper())):
            table = _lut3d_table(apply, n, coordinates, out, M)
            group = _lut3d_group(table, coordinates, out, M)
            baked = apply_cpu(_cpu(group), X)
            found = DeltaEStats.from_values(delta_E(to_XYZ(baked), reference, white_XYZ))
            if found.max <= max_delta_E:
                return BakedTransform("lut3d", group, M, n, out, found, coordinates, table)
            error = found if error is None or found.max < error.max else error
    raise CamcalError(
        f"a {sizes[-1]}^3 Lut3D still leaves CIEDE2000 up to {error.max:.3f} over the samples "
        f"(allowed {max_delta_E:g}); allow a larger bake error or refit with a smoother model"
    )


# --------------------------------------------------------------------------
# Pieces of a camera colour space.


def linearisation_transforms(linearisation: Linearisation) -> tuple[list, float]:
    """OCIO transforms of a fit's linearisation, and their largest error.

    Parameters
    ----------
    linearisation
        The fit's per-channel curves.

    Returns
    -------
    transforms, error
        A list of OCIO transforms (empty for the identity) and the largest
        relative error ``|L_ocio - L| / max(L(1), 1e-6)`` over code values in
        [0, 1] (0 for exact forms: identity, gamma-offset, lut1d).

    Notes
    -----
    ``gamma-offset`` ``L = k max(V - o, 0)^g`` is exact:
    ``MatrixTransform(offset -o) -> ExponentTransform(g, negatives clamp)
    -> MatrixTransform(diag k)``. ``lut1d`` curves of equal length are a
    ``Lut1DTransform`` with their samples (linear interpolation, as in
    camcal). Other curves (``named``, mixtures) are sampled at 4096 code
    values.
    """
    ocio = _ocio()
    channels = linearisation.channels
    kinds = {c.kind for c in channels}
    if kinds == {"none"}:
        return [], 0.0
    if kinds == {"gamma-offset"}:
        p = [c.params for c in channels]
        return [
            _matrix_transform(np.eye(3), [-q["offset"] for q in p]),
            ocio.ExponentTransform([q["gamma"] for q in p] + [1.0], negativeStyle=ocio.NEGATIVE_CLAMP),
            _matrix_transform(np.diag([q["gain"] for q in p])),
        ], 0.0
    lengths = {len(c.params.get("samples", ())) for c in channels}
    exact = kinds == {"lut1d"} and len(lengths) == 1
    n = lengths.pop() if exact else CURVE_SAMPLES
    codes = np.linspace(0.0, 1.0, n)
    table = np.stack([np.asarray(c.params["samples"]) if exact else c.apply(codes) for c in channels], axis=-1)
    lut = ocio.Lut1DTransform(n, False)
    lut.setInterpolation(ocio.INTERP_LINEAR)
    lut.setData(np.ascontiguousarray(table, dtype=np.float32).ravel())
    if exact:
        return [lut], 0.0
    probe = np.linspace(0.0, 1.0, 4 * n + 1)
    truth = linearisation.apply(np.repeat(probe[:, None], 3, axis=1))
    got = apply_cpu(_cpu(lut), np.repeat(probe[:, None], 3, axis=1))
    scale = np.maximum(np.abs(truth[-1]), 1e-6)
    return [lut], float(np.max(np.abs(got - truth) / scale))


def _aces_to_reference(config) -> np.ndarray:
    """Matrix from ACES2065-1 (the ``aces_interchange`` role) to the config's scene reference."""
    ocio = _ocio()
    name = config.getRoleColorSpace("aces_interchange") if config.hasRole("aces_interchange") else None
    space = config.getColorSpace(name) if name else None
    if space is None:
        raise CamcalError("the base config has no aces_interchange role: cannot place camera XYZ in its reference")
    to_ref = space.getTransform(ocio.COLORSPACE_DIR_TO_REFERENCE)
    if to_ref is not None:
        processor = config.getProcessor(to_ref)
    else:
        from_ref = space.getTransform(ocio.COLORSPACE_DIR_FROM_REFERENCE)
        if from_ref is None:
            return np.eye(3)
        processor = config.getProcessor(from_ref, ocio.TRANSFORM_DIR_INVERSE)
    cpu = processor.getDefaultCPUProcessor()
    A = apply_cpu(cpu, np.vstack([np.eye(3), np.zeros((1, 3))]))
    M = (A[:3] - A[3]).T
    probe = np.random.default_rng(0).uniform(0.0, 2.0, (16, 3))
    if np.abs(A[3]).max() > 1e-6 or np.abs(apply_cpu(cpu, probe) - probe @ M.T).max() > 1e-4:
        raise CamcalError(f"the base config's {name!r} -> reference transform is not a matrix")
    return M


def XYZ_to_reference_matrix(config, white_XYZ: Any, cat: str = "Bradford") -> np.ndarray:
    """Matrix from XYZ under ``white_XYZ`` (Y = 1) to the config's scene reference.

    Parameters
    ----------
    config
        The ``PyOpenColorIO.Config`` (needs the ``aces_interchange`` role).
    white_XYZ
        White of the XYZ (the fit's target white).
    cat
        ``"Bradford"`` (OCIO's ACES configs) or ``"CAT02"``.

    Returns
    -------
    numpy.ndarray
        ``(3, 3)``: ``M_ref = A_ref @ M_AP0 @ CAT(white -> ACES white)`` with
        ``M_AP0`` the ACES2065-1 ``XYZ -> RGB`` matrix (colour-science).
    """
    import colour

    if cat not in CATS:
        raise CamcalError(f"unknown adaptation {cat!r}, expected one of: {', '.join(CATS)}")
    aces = colour.RGB_COLOURSPACES["ACES2065-1"]
    aces_white = colour.xy_to_XYZ(aces.whitepoint)
    adapt = colour.adaptation.matrix_chromatic_adaptation_VonKries(
        np.asarray(white_XYZ, dtype=np.float64), aces_white, transform=cat)
    return _aces_to_reference(config) @ aces.matrix_XYZ_to_RGB @ adapt


def _newton_inverse(apply: Callable[[np.ndarray], np.ndarray], XYZ: np.ndarray, x: np.ndarray,
                    iterations: int) -> np.ndarray:
    """Damped Newton steps (central-difference Jacobians, steps clipped to 0.1) towards ``apply(x) = XYZ``."""
    h = 1e-6
    for _ in range(iterations):
        F = apply(x) - XYZ
        if np.abs(F).max() < 1e-12:
            break
        J = np.stack([(apply(x + h * e) - apply(x - h * e)) / (2 * h) for e in np.eye(3)], axis=-1)
        try:
            step = np.linalg.solve(J, F[..., None])[..., 0]
        except np.linalg.LinAlgError:
            break
        x = x - np.clip(step, -0.1, 0.1)
    return x


def invert_model(apply: Callable[[np.ndarray], np.ndarray], XYZ: Any, iterations: int = 40) -> np.ndarray:
    """Linear camera RGB whose ``apply`` gives ``XYZ``: damped Newton from two starts.

    A non-linear fit (root-polynomial, polynomial) can map several RGB to the
    same XYZ; the physical preimage of a reflective colour has non-negative
    RGB. Newton starts from the nearest point (relative XYZ distance) of a
    non-negative 25^3 RGB grid and from the best linear inverse; per target
    the converged solution (residual < 1e-9) with the least negative
    component is kept.

    Parameters
    ----------
    apply
        The fit's ``RGB -> XYZ``.
    XYZ
        ``(N, 3)`` targets.

    Returns
    -------
    numpy.ndarray
        ``(N, 3)`` RGB (the last iterate where Newton did not converge).
    """
    XYZ = np.asarray(XYZ, dtype=np.float64).reshape(-1, 3)
    g = np.linspace(0.0, 1.0, 25)
    grid = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
    mapped = apply(grid)
    scale = np.linalg.norm(XYZ, axis=1) + 1e-3
    nearest = np.array([np.argmin(np.linalg.norm(mapped - target, axis=1)) for target in XYZ], dtype=int)
    coarse = grid.reshape(25, 25, 25, 3)[::6, ::6, ::6].reshape(-1, 3)  # 5^3: 0, 0.25 ... 1
    M = np.linalg.lstsq(coarse, apply(coarse), rcond=None)[0].T
    candidates = [_newton_inverse(apply, XYZ, start, iterations)
                  for start in (grid[nearest], XYZ @ np.linalg.inv(M).T)]
    scores = []
    for x in candidates:
        residual = np.abs(apply(x) - XYZ).max(axis=1) / scale
        scores.append(np.where(residual < 1e-9, 0.0, 10.0 + residual) + np.maximum(-x.min(axis=1), 0.0))
    best = np.argmin(np.stack(scores), axis=0)
    return np.stack(candidates)[best, np.arange(len(XYZ))]


def _hull_samples(patches: np.ndarray, n: int) -> np.ndarray:
    """``patches`` plus the points of an ``n^3`` grid over their box inside the hull of them and them / 4."""
    from scipy.spatial import Delaunay

    vertices = np.vstack([patches, patches / 4.0])
    low, high = vertices.min(axis=0), vertices.max(axis=0)
    axes = [np.linspace(lo, hi, n) for lo, hi in zip(low, high)]
    grid = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
    inside = Delaunay(vertices).find_simplex(grid) >= 0
    return np.vstack([patches, grid[inside]])


def chart_gamut_samples(fit: ColourFit, n: int = 21) -> np.ndarray:
    """Linear camera RGB spanning the chart gamut of a characterisation.

    The chart is the fit's reference chart (the ColorChecker 24 when none is
    recorded or the reference is not a chart, e.g. a spectral training
    set), its XYZ adapted (CAT02) to the fit's target white and
    inverted through the fit (:func:`invert_model`; only converged
    preimages a camera records, see :func:`plausible_surface_samples`); an
    RBF fit adds its centres (its training patches). The samples are those
    patches plus the points of a regular ``n^3`` grid over their bounding
    box that lie in the convex hull of the patches and of the same patches
    two stops darker (divided by 4). Black itself is left out: near it
    CIEDE2000 magnifies absolute errors that no image shows.

    Returns
    -------
    numpy.ndarray
        ``(M, 3)`` linear camera RGB.
    """
    return _chart_samples(fit.model, fit.target_white_XYZ, fit.reference, n)


def _chart_samples(model, white_XYZ: Any, reference: str | None, n: int = 21) -> np.ndarray:
    from camcal.colour.chart import DEFAULT_CHART, reference_chart
    from camcal.colour.spectral import adapt_XYZ

    try:
        chart = reference_chart(reference or DEFAULT_CHART, "D50")
    except CamcalError:  # not a chart (e.g. a spectral training set): the default chart's gamut
        chart = reference_chart(DEFAULT_CHART, "D50")
    white = np.asarray(white_XYZ, dtype=np.float64)
    XYZ = chart.XYZ if np.allclose(chart.white_XYZ, white, atol=1e-6) else adapt_XYZ(
        chart.XYZ, chart.white_XYZ, white, "CAT02")
    patches = _recordable_preimages(model.apply, XYZ)
    if getattr(model, "kind", "") == "rbf":
        patches = np.vstack([patches, model.centres])
    return _hull_samples(patches, n)


#: Reflectances of the plausible surface colours: the CIE 13.3 test colour samples.
SURFACE_REFLECTANCES = "CIE 1995"
#: CIELAB lightness levels and a*, b* step of the Pointer's-gamut grid of plausible surface colours.
POINTER_LIGHTNESS = (15.0, 30.0, 45.0, 60.0, 75.0, 90.0)
POINTER_STEP = 10.0
#: Smallest channel of a plausible surface's camera RGB, relative to its largest.
MIN_CHANNEL_RATIO = 0.02


def plausible_surface_XYZ(white_XYZ: Any, illuminant: str | None = None) -> np.ndarray:
    """XYZ of plausible surface colours under a white: test colour samples and a Pointer's-gamut grid.

    Parameters
    ----------
    white_XYZ
        White of the output XYZ (Y = 1).
    illuminant
        CIE illuminant the reflectances are lit by (``SDS_ILLUMINANTS``
        name); ``None`` or an unknown name uses D65. Their XYZ are adapted
        (CAT02) from the illuminant's white to ``white_XYZ``.

    Returns
    -------
    numpy.ndarray
        ``(N, 3)``: the 14 CIE 13.3 test colour samples, then the CIELAB
        grid (lightness :data:`POINTER_LIGHTNESS`, a*, b* every
        :data:`POINTER_STEP`) inside Pointer's gamut of real surface colours
        (tested under its illuminant C after CAT02).

    References
    ----------
    - Pointer, M. R. (1980). The gamut of real surface colours. Color
      Research & Application, 5(3), 145-155.
    - CIE 13.3-1995: Method of measuring and specifying colour rendering
      properties of light sources (test colour samples).
    """
    import colour
    from colour.quality.datasets import SDS_TCS

    from camcal.colour.spectral import adapt_XYZ, illuminant_white_XYZ

    white = np.asarray(white_XYZ, dtype=np.float64)
    name = illuminant if illuminant in colour.SDS_ILLUMINANTS else "D65"
    shape = colour.SpectralShape(380, 780, 5)
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"].copy().align(shape).values
    light = colour.SDS_ILLUMINANTS[name].copy().align(shape).values
    R = np.array([sd.copy().align(shape).values for sd in SDS_TCS[SURFACE_REFLECTANCES].values()])
    XYZ = (R * light) @ cmfs / (light @ cmfs[:, 1])
    source_white = light @ cmfs / (light @ cmfs[:, 1])
    if not np.allclose(source_white, white, atol=1e-4):
        XYZ = adapt_XYZ(XYZ, source_white, white, "CAT02")
    ab = np.arange(-120.0, 120.0 + 1e-9, POINTER_STEP)
    Lab = np.stack(np.meshgrid(POINTER_LIGHTNESS, ab, ab, indexing="ij"), axis=-1).reshape(-1, 3)
    grid = colour.Lab_to_XYZ(Lab, colour.XYZ_to_xy(white))
    C = illuminant_white_XYZ("C")
    inside = colour.volume.is_within_pointer_gamut(adapt_XYZ(grid, white, C, "CAT02"))
    return np.vstack([XYZ, grid[inside]])


def plausible_surface_samples(apply: Callable[[np.ndarray], np.ndarray], white_XYZ: Any,
                              illuminant: str | None = None) -> np.ndarray:
    """Linear camera RGB of :func:`plausible_surface_XYZ`, inverted through ``apply``.

    Only preimages a camera records from a surface are kept: Newton
    converged (:func:`invert_model`) and no channel below
    :data:`MIN_CHANNEL_RATIO` of the largest one. Broadband reflectances
    under a broadband light never zero a channel of a camera whose
    sensitivities overlap; colours that would need it lie on the edge of the
    camera's own gamut.

    Returns
    -------
    numpy.ndarray
        ``(M, 3)`` linear camera RGB.
    """
    return _recordable_preimages(apply, plausible_surface_XYZ(white_XYZ, illuminant))


def _recordable_preimages(apply: Callable[[np.ndarray], np.ndarray], XYZ: np.ndarray) -> np.ndarray:
    """:func:`invert_model`, keeping converged preimages with no channel below :data:`MIN_CHANNEL_RATIO`."""
    RGB = invert_model(apply, XYZ)
    with np.errstate(invalid="ignore"):
        residual = np.abs(apply(RGB) - XYZ).max(axis=1) / (np.linalg.norm(XYZ, axis=1) + 1e-3)
        keep = (residual < 1e-6) & (RGB.min(axis=1) >= MIN_CHANNEL_RATIO * RGB.max(axis=1))
    return RGB[keep & np.all(np.isfinite(RGB), axis=1)]


def bake_samples(fit: ColourFit) -> np.ndarray:
    """Where a baked fit must hold: :func:`chart_gamut_samples` and :func:`plausible_surface_samples`.

    The surfaces are lit by the fit's training illuminant and adapted to its
    target white, as the fit's own reference XYZ were.
    """
    return _model_samples(fit.model, fit.target_white_XYZ, fit.reference, fit.training_illuminant)


def _model_samples(model, white_XYZ: Any, reference: str | None, illuminant: str | None) -> np.ndarray:
    surfaces = plausible_surface_samples(model.apply, white_XYZ, illuminant)
    return np.vstack([_chart_samples(model, white_XYZ, reference), surfaces])


def bake_model(model, white_XYZ: Any, *, reference: str | None = None, illuminant: str | None = None,
               max_delta_E: float = 0.2, lut_sizes: Sequence[int] = LUT_SIZES) -> BakedTransform:
    """A characterisation model as OCIO transforms: the one check every exporter and ``auto`` share.

    A ``matrix3x3`` model is an exact ``MatrixTransform``; any other is baked
    (:func:`transform_from_callable`) over the chart gamut of ``reference``
    and the plausible surface colours lit by ``illuminant``
    (:func:`bake_samples`), within ``max_delta_E`` CIEDE2000 or refused.

    Parameters
    ----------
    model
        ``LinearTermsModel`` or ``RBFModel`` (linear camera RGB -> XYZ).
    white_XYZ
        The model's target white (Y = 1).
    reference, illuminant
        The fit's reference chart and training illuminant.
    max_delta_E, lut_sizes
        See :func:`transform_from_callable`.

    Raises
    ------
    CamcalError
        The largest Lut3D still exceeds ``max_delta_E`` somewhere.
    """
    if model.kind == "matrix3x3":
        return transform_from_callable(model.apply, matrix=model.M)
    return transform_from_callable(model.apply, samples=_model_samples(model, white_XYZ, reference, illuminant),
                                   white_XYZ=white_XYZ, max_delta_E=max_delta_E, lut_sizes=lut_sizes)


def bake_fit(fit: ColourFit, *, max_delta_E: float = 0.2, lut_sizes: Sequence[int] = LUT_SIZES) -> BakedTransform:
    """:func:`bake_model` of a characterisation's model (exact matrix, or the baked Lut3D)."""
    return bake_model(fit.model, fit.target_white_XYZ, reference=fit.reference,
                      illuminant=fit.training_illuminant, max_delta_E=max_delta_E, lut_sizes=lut_sizes)


# --------------------------------------------------------------------------
# Describe, then build.


@dataclass(frozen=True, eq=False)
class ColourSpaceSpec:
    """A colour space to add: its transform to the scene reference and its files.

    Attributes
    ----------
    name, family, description, encoding
        As OCIO takes them (``encoding``: ``scene-linear``, ``log``...).
    to_reference
        OCIO transforms applied in order, from this space to the reference.
    files
        ``{relative path: text}`` written beside the config (CLF files under
        ``luts/``, which the config's search path holds).
    categories
        OCIO categories (``file-io`` lists it for reading images).
    """

    name: str
    family: str
    description: str
    to_reference: tuple
    encoding: str = "scene-linear"
    files: dict = field(default_factory=dict)
    categories: tuple[str, ...] = ("file-io",)


@dataclass(frozen=True, eq=False)
class LookSpec:
    """A Look: a transform applied in ``process_space`` (e.g. a camera match).

    ``transform`` is an OCIO transform (a ``FileTransform`` to a CLF listed in
    ``files``, or an inline ``MatrixTransform``/``GroupTransform``).
    """

    name: str
    process_space: str
    transform: Any
    description: str = ""
    files: dict = field(default_factory=dict)


@dataclass(frozen=True, eq=False)
class ConfigSpec:
    """A config: a base plus colour spaces and looks.

    ``base``: ``"camcal"`` (``ocio_configs/camcal_base.ocio``), an ``ocio://``
    built-in (default: the ACES studio config) or a ``.ocio`` file.
    """

    base: str = STUDIO_CONFIG
    colour_spaces: tuple[ColourSpaceSpec, ...] = ()
    looks: tuple[LookSpec, ...] = ()
    name: str | None = None

    @property
    def files(self) -> dict:
        out: dict = {}
        for item in (*self.colour_spaces, *self.looks):
            out.update(item.files)
        return out


def add_look(config, look: LookSpec) -> None:
    """Add a Look to an editable ``PyOpenColorIO.Config``.

    Parameters
    ----------
    config
        The config (``createEditableCopy()`` of a loaded one).
    look
        Name, process space (must exist in the config), transform.

    Raises
    ------
    CamcalError
        The process space is missing or the name is taken.
    """
    ocio = _ocio()
    if config.getColorSpace(look.process_space) is None:
        raise CamcalError(f"look {look.name!r}: process space {look.process_space!r} is not in the config")
    if config.getLook(look.name) is not None:
        raise CamcalError(f"look {look.name!r} already exists in the base config")
    config.addLook(ocio.Look(name=look.name, processSpace=look.process_space, transform=look.transform,
                             description=look.description))


def build_ocio_config(spec: ConfigSpec):
    """Build and validate the config a :class:`ConfigSpec` describes.

    The base is loaded, its search paths are made absolute (a file base's
    own LUTs stay reachable from the new config's folder) and ``luts`` is
    appended, the colour spaces and looks are added and ``config.validate()``
    runs; its errors propagate (as :class:`CamcalError`).

    Returns
    -------
    PyOpenColorIO.Config
    """
    ocio = _ocio()
    config = load_base_config(spec.base)
    if spec.name:
        config.setName(spec.name)
    # the base's own LUT folders, made absolute (the new config lives elsewhere), then luts/
    working = config.getWorkingDir()
    paths = [p if os.path.isabs(p) or not working else str(Path(working, p)) for p in config.getSearchPaths()]
    config.clearSearchPaths()
    for path in paths + ([LUT_DIR] if spec.files and LUT_DIR not in paths else []):
        config.addSearchPath(path)
    for space in spec.colour_spaces:
        if config.getColorSpace(space.name) is not None:
            raise CamcalError(f"colour space {space.name!r} already exists in the base config")
        cs = ocio.ColorSpace(referenceSpace=ocio.REFERENCE_SPACE_SCENE, name=space.name, family=space.family,
                             encoding=space.encoding, description=space.description,
                             categories=list(space.categories))
        cs.setTransform(ocio.GroupTransform(list(space.to_reference)), ocio.COLORSPACE_DIR_TO_REFERENCE)
        config.addColorSpace(cs)
    for look in spec.looks:
        add_look(config, look)
    try:
        config.validate()
    except ocio.Exception as error:
        raise CamcalError(f"the OCIO config does not validate: {error}") from None
    return config


def write_ocio_config(spec: ConfigSpec, directory: str | os.PathLike, filename: str = "config.ocio") -> Path:
    """Write the config and its files into ``directory``, each atomically, the config last.

    The config is built and validated before anything is written.

    Returns
    -------
    Path
        The config file.
    """
    config = build_ocio_config(spec)
    text = config.serialize()
    directory = Path(directory)
    for relative, content in spec.files.items():
        atomic_write_text(directory / relative, content)
    path = directory / filename
    atomic_write_text(path, text)
    return path


# --------------------------------------------------------------------------
# Characterisation fits.


@dataclass(frozen=True)
class SpaceExport:
    """What one exported camera colour space is, with its figures.

    ``bake_error``: CIEDE2000 of the baked model over the chart gamut and plausible surface colours
    (``None`` for an exact matrix); ``linearisation_error``: relative error
    of a sampled linearisation (0 when exact); ``clf``: the CLF's path
    relative to the config (``None`` for a matrix fit).
    """

    name: str
    camera: str
    model: str
    kind: str
    lut_size: int | None
    bake_error: DeltaEStats | None
    linearisation_error: float
    clf: str | None

    def summary(self) -> str:
        line = f"{self.name}: {self.model}, "
        if self.kind == "matrix":
            line += "exact MatrixTransform"
        else:
            line += (f"{self.lut_size}^3 Lut3D in {self.clf}, bake error CIEDE2000 mean "
                     f"{self.bake_error.mean:.3f}, max {self.bake_error.max:.3f} over the chart gamut and plausible surfaces")
        if self.linearisation_error:
            line += f"; sampled linearisation, relative error {self.linearisation_error:.1e}"
        return line


@dataclass(frozen=True)
class OCIOExport:
    """The written config and its camera spaces."""

    config_path: Path
    base: str
    spaces: tuple[SpaceExport, ...]


def _held_out(evaluation: dict) -> str:
    for key, label in (("test", "independent patches"), ("loo", "leave-one-out"), ("train", "training")):
        stats = evaluation.get(key)
        if stats:
            return (f"held-out CIEDE2000 ({label}, n = {stats['n']}): mean {stats['mean']:.2f}, "
                    f"p95 {stats['p95']:.2f}, max {stats['max']:.2f}")
    return ""  # pragma: no cover - train is always present


def colour_space_from_fit(
    fit: ColourFit,
    camera: str,
    config,
    *,
    cat: str = "Bradford",
    max_delta_E: float = 0.2,
    lut_sizes: Sequence[int] = LUT_SIZES,
) -> tuple[ColourSpaceSpec, SpaceExport]:
    """The input colour space of a characterisation, for ``config``'s reference.

    Parameters
    ----------
    fit
        The characterisation.
    camera
        Camera name; the space is ``camcal <camera>``.
    config
        The base config (its ``aces_interchange`` role places ACES2065-1).
    cat, max_delta_E, lut_sizes
        See :func:`XYZ_to_reference_matrix` and :func:`transform_from_callable`.

    Returns
    -------
    ColourSpaceSpec, SpaceExport
    """
    ocio = _ocio()
    name = colour_space_name(camera)
    lin, lin_error = linearisation_transforms(fit.linearisation)
    to_ref = XYZ_to_reference_matrix(config, fit.target_white_XYZ, cat)
    model = fit.model
    files: dict = {}
    clf = None
    baked = bake_fit(fit, max_delta_E=max_delta_E, lut_sizes=lut_sizes)
    if baked.kind == "matrix":
        steps = [*lin, _matrix_transform(to_ref @ baked.matrix)]
        how = "exact matrix"
    else:
        clf = f"{LUT_DIR}/camcal_{_slug(camera)}.clf"
        how = (f"baked as a log-chromaticity shaper and {baked.lut_size}^3 Lut3D ({clf}), bake error CIEDE2000 mean "
               f"{baked.bake_error.mean:.3f}, max {baked.bake_error.max:.3f} over the chart gamut and plausible surfaces")
        files[clf] = baked.clf_text(f"camcal:{_slug(camera)}",
                                    f"camcal {model.label}: linear camera RGB of {camera} to CIE XYZ "
                                    f"({fit.target_white}, white Y = 1)")
        steps = [*lin, ocio.FileTransform(Path(clf).name, interpolation=ocio.INTERP_TETRAHEDRAL),
                 _matrix_transform(to_ref)]
    description = (f"camcal characterisation of camera {camera}: {model.label}, linearisation "
                   f"{fit.linearisation.label}; {_held_out(fit.evaluation)}; XYZ ({fit.target_white}) "
                   f"to the reference with {cat}; model {how}.")
    spec = ColourSpaceSpec(name, FAMILY, description, tuple(steps), files=files)
    report = SpaceExport(name, camera, model.label, baked.kind, baked.lut_size, baked.bake_error, lin_error, clf)
    return spec, report


def look_name(source: str, target: str) -> str:
    """The Look of a camera match: ``camcal match <source> to <target>``."""
    return f"camcal match {source} to {target}"


def look_from_match(match, config, *, max_delta_E: float = 0.2,
                    lut_sizes: Sequence[int] = LUT_SIZES) -> tuple[LookSpec, SpaceExport]:
    """A camera match (kind ``match``) as an OCIO Look on linear camera values.

    The Look's process space is the config's ``data`` role (no conversion):
    applied to camera B's *linear* RGB it gives camera A's linear RGB
    (``match.apply``). A matrix match is an exact ``MatrixTransform``; the
    others are baked like a characterisation (:func:`transform_from_callable`)
    over a cube of linear RGB from 1/64 to 1, the error measured with the
    outputs read as linear Rec. 709 / D65 (camera A's RGB has no XYZ here).
    """
    import colour  # noqa: PLC0415

    ocio = _ocio()
    process_space = config.getRoleColorSpace(ocio.ROLE_DATA) if config.hasRole(ocio.ROLE_DATA) else None
    if not process_space:
        raise CamcalError("the base config has no 'data' role: a match Look needs a space without conversion")
    source, target = match.source or "B", match.target or "A"
    name = look_name(source, target)
    files: dict = {}
    clf = None
    if match.matrix is not None:
        baked = transform_from_callable(match.apply, matrix=match.matrix)
        transform = _matrix_transform(baked.matrix)
    else:
        levels = np.geomspace(1.0 / 64.0, 1.0, 9)
        cube = np.stack(np.meshgrid(levels, levels, levels, indexing="ij"), axis=-1).reshape(-1, 3)
        rec709 = colour.RGB_COLOURSPACES["ITU-R BT.709"]
        baked = transform_from_callable(
            match.apply, samples=cube, white_XYZ=colour.xy_to_XYZ(rec709.whitepoint),
            to_XYZ=lambda RGB: RGB @ rec709.matrix_RGB_to_XYZ.T, max_delta_E=max_delta_E, lut_sizes=lut_sizes,
        )
        clf = f"{LUT_DIR}/camcal_match_{_slug(source)}_to_{_slug(target)}.clf"
        files[clf] = baked.clf_text(f"camcal:match:{_slug(source)}:{_slug(target)}",
                                    f"camcal {match.model.label}: linear {source} RGB to linear {target} RGB")
        transform = ocio.FileTransform(Path(clf).name, interpolation=ocio.INTERP_TETRAHEDRAL)
    description = (f"camcal colour match of camera {source} to camera {target} ({match.model.label}) on linear "
                   f"camera values; {_held_out(match.evaluation)}")
    look = LookSpec(name, process_space, transform, description=description, files=files)
    report = SpaceExport(name, source, match.model.label, baked.kind, baked.lut_size, baked.bake_error, 0.0, clf)
    return look, report


def export_ocio(
    fits: Sequence[tuple[str, ColourFit]],
    directory: str | os.PathLike,
    *,
    base: str = STUDIO_CONFIG,
    cat: str = "Bradford",
    max_delta_E: float = 0.2,
    lut_sizes: Sequence[int] = LUT_SIZES,
    matches: Sequence = (),
) -> OCIOExport:
    """Write ``directory/config.ocio`` (+ ``luts/*.clf``): ``base`` plus one space per camera.

    Parameters
    ----------
    fits
        ``(camera name, fit)`` pairs; names must be unique.
    directory
        Output folder.
    base, cat, max_delta_E, lut_sizes
        See :class:`ConfigSpec` and :func:`colour_space_from_fit`.
    matches
        Camera matches (kind ``match``), each written as a Look
        (:func:`look_from_match`).

    Returns
    -------
    OCIOExport
        ``spaces`` lists the colour spaces, then the Looks.
    """
    names = [camera for camera, _ in fits]
    if len(set(names)) != len(names):
        raise CamcalError(f"camera names must be unique, got {', '.join(names)}")
    config = load_base_config(base)
    specs, reports = [], []
    for camera, fit in fits:
        spec, report = colour_space_from_fit(fit, camera, config, cat=cat, max_delta_E=max_delta_E,
                                             lut_sizes=lut_sizes)
        specs.append(spec)
        reports.append(report)
    looks = []
    for match in matches:
        look, report = look_from_match(match, config, max_delta_E=max_delta_E, lut_sizes=lut_sizes)
        looks.append(look)
        reports.append(report)
    path = write_ocio_config(ConfigSpec(base=str(base), colour_spaces=tuple(specs), looks=tuple(looks)), directory)
    return OCIOExport(path, str(base), tuple(reports))


# --------------------------------------------------------------------------
# Applying a fit to images: one OCIO CPU processor.

#: Output spaces of :func:`fit_processor`: name -> colour-science RGB colour space (``None``: the fit's XYZ).
OUTPUT_SPACES = {"CIE XYZ": None, "ACES2065-1": "ACES2065-1", "ACEScg": "ACEScg", "lin Rec.709": "ITU-R BT.709"}


def output_matrix(white_XYZ: Any, space: str, cat: str = "Bradford") -> np.ndarray:
    """Matrix from XYZ under ``white_XYZ`` (Y = 1) to a linear output space of :data:`OUTPUT_SPACES`.

    ``"CIE XYZ"`` is the identity (the fit's own XYZ, relative to its target
    white); the RGB spaces are ``M_XYZ->RGB @ CAT(white -> space white)``
    (von Kries with ``cat``; colour-science's matrices: ACES2065-1 AP0,
    ACEScg AP1, both with the ACES white; linear Rec. 709 with D65).

    Examples
    --------
    >>> output_matrix([0.95047, 1.0, 1.08883], "CIE XYZ").tolist()[0]
    [1.0, 0.0, 0.0]
    """
    import colour

    if space not in OUTPUT_SPACES:
        raise CamcalError(f"unknown output space {space!r}, expected one of: {', '.join(OUTPUT_SPACES)}")
    if cat not in CATS:
        raise CamcalError(f"unknown adaptation {cat!r}, expected one of: {', '.join(CATS)}")
    if OUTPUT_SPACES[space] is None:
        return np.eye(3)
    rgb = colour.RGB_COLOURSPACES[OUTPUT_SPACES[space]]
    adapt = colour.adaptation.matrix_chromatic_adaptation_VonKries(
        np.asarray(white_XYZ, dtype=np.float64), colour.xy_to_XYZ(rgb.whitepoint), transform=cat)
    return rgb.matrix_XYZ_to_RGB @ adapt


@dataclass(frozen=True, eq=False)
class FitProcessor:
    """A characterisation applied to images by one OCIO CPU processor.

    The processor is the exported colour space's own transform: the
    linearisation (exact, or sampled for ``named`` curves), the model (an
    exact ``MatrixTransform`` for ``matrix3x3``; otherwise the baked
    log-chromaticity Lut3D of :func:`bake_fit`, within ``bake_error`` of the
    fit), then the matrix to ``space`` (:func:`output_matrix`).

    Attributes
    ----------
    space
        Output space (a key of :data:`OUTPUT_SPACES`).
    kind
        ``"matrix"`` (exact) or ``"lut3d"`` (baked).
    bake_error
        CIEDE2000 of the bake over the chart gamut and plausible surfaces
        (``None`` when exact).
    cpu
        The ``PyOpenColorIO.CPUProcessor``.
    """

    space: str
    kind: str
    bake_error: DeltaEStats | None
    cpu: Any

    def apply(self, codes: Any, *, in_place: bool = False) -> np.ndarray:
        """Code values ``(..., 3)`` in [0, 1] to ``space``, float32, same shape.

        ``in_place``: a C-contiguous float32 array is processed in place (no copy).
        """
        if in_place and isinstance(codes, np.ndarray) and codes.dtype == np.float32 and codes.flags.c_contiguous:
            pixels = codes
        else:
            pixels = np.array(codes, dtype=np.float32, order="C", copy=True)
        if pixels.shape[-1] != 3:
            raise CamcalError(f"expected pixels with 3 channels (..., 3), got shape {pixels.shape}")
        self.cpu.applyRGB(pixels)
        return pixels


def fit_processor(fit: ColourFit, space: str = "CIE XYZ", *, cat: str = "Bradford", max_delta_E: float = 0.2,
                  lut_sizes: Sequence[int] = LUT_SIZES) -> FitProcessor:
    """The OCIO CPU processor of a characterisation, from code values to ``space``.

    Parameters
    ----------
    fit
        The characterisation.
    space
        ``"CIE XYZ"`` (the fit's XYZ, target white Y = 1), ``"ACES2065-1"``,
        ``"ACEScg"`` or ``"lin Rec.709"``.
    cat, max_delta_E, lut_sizes
        See :func:`output_matrix` and :func:`bake_fit` (a fit the exporter
        refuses is refused here too).

    Returns
    -------
    FitProcessor
    """
    ocio = _ocio()
    out = output_matrix(fit.target_white_XYZ, space, cat)
    lin, _ = linearisation_transforms(fit.linearisation)
    baked = bake_fit(fit, max_delta_E=max_delta_E, lut_sizes=lut_sizes)
    if baked.kind == "matrix":
        steps = [*lin, _matrix_transform(out @ baked.matrix)]
    else:
        steps = [*lin, *list(baked.transform), _matrix_transform(out)]
    cpu = _cpu(ocio.GroupTransform(steps))
    return FitProcessor(space, baked.kind, baked.bake_error, cpu)
