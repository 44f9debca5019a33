"""Flat field and vignetting: the per-channel gain of a lens over the frame, fitted from a grey card or from
neutral patches seen at several places, applied (divided out) and its inverse.

The model (per channel ``c``, pixel ``(x, y)``, pixel (0, 0) at the centre of
the top-left pixel)::

    G_c(x, y) = V_c(r) * S_c(x, y)
    V_c(r)    = 1 + k1_c r^2 + k2_c r^4 + k3_c r^6
    r         = |(x, y) - centre| / R,   R = hypot((W - 1) / 2, (H - 1) / 2)
    S_c       = exp(P_c(u, v)),  (u, v) = ((x, y) - centre) / R

``V`` is Lensfun's ``pa`` vignetting model (Pablo d'Angelo's polynomial, as
Hugin fits it) with Lensfun's radius: 1 at the half diagonal of the image
measured between the extreme pixel centres, about the optical centre
(Lensfun 0.3.4, mod-color.cpp: "for vignetting it uses 1.0 = half diagonal
length"; checked against lensfunpy in the tests). ``S`` is an optional smooth
non-radial term, ``P_c`` a 2D polynomial of total degree 1 to
``smooth_degree`` with no constant, so that ``G_c = 1`` at the optical centre
in every channel: a flat field corrects falloff and colour shading, never
the white balance at the centre. A linear image is corrected by dividing it
by ``G`` (:func:`correct_flat_field`); :func:`apply_vignetting` multiplies.

The fit (:func:`fit_flat_field`) works on samples: block medians of grey-card
images (:func:`samples_from_images`) or the values of neutral patches at
their positions (:func:`samples_from_patches`). Each sample is
``A_s rho_{p,c} G_c(x, y)``: ``A`` the exposure of shot ``s`` (each image is
a shot; one factor for all channels: the same light), ``rho`` the value of
patch ``p`` at the centre of the first shot. Everything is fitted together by Levenberg-Marquardt on
``log`` values weighted by each sample's noise: first iteratively reweighted
(Cauchy weights), then the samples beyond 6 sigma and 2 % are rejected and
the inliers refitted. (A tilt in ``S`` and a shifted centre describe nearly
the same data: with a smooth term the centre is loosely determined, the gain
is not.) The gain's uncertainty is propagated from the fit's covariance (it
covers the samples' noise, not a model that does not hold the lens; the
residual says that).

References
----------
Lensfun, libs/lensfun/mod-color.cpp (``ModifyColor_DeVignetting_PA``) and
https://lensfun.github.io/manual/latest/group__Lens.html (``lfVignettingModel``).
Goldman, D. B. (2010). Vignette and exposure calibration and compensation.
IEEE TPAMI 32(12), 2276-2288 (the polynomial in r^2 about the optical centre).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np
import scipy.optimize
from numpy.typing import NDArray

from camcal.base.errors import CamcalError
from camcal.base.fields import integer_field, keys_field, matrix_field, number_field, string_field, vector_field
from camcal.colour.flatfield_samples import FlatFieldSamples, check_image, samples_from_images, samples_from_patches

__all__ = ["FORMAT", "FORMAT_VERSION", "FlatField", "FlatFieldSamples", "RadialTerms", "apply_vignetting",
           "common_radial_terms", "correct_flat_field", "fit_flat_field", "half_diagonal", "samples_from_images",
           "samples_from_patches"]

#: The ``format`` and ``version`` a flat-field file carries.
FORMAT = "camcal flat field"
FORMAT_VERSION = 1
#: Samples must reach this normalised radius: below it the corners are extrapolated too far.
MIN_REACH = 0.5
#: The first robust fit uses the samples within this radius (half diagonals) of the image centre.
MIDDLE = 0.6
#: Samples farther than this many sigma (and this relative difference) from the robust fit are rejected.
REJECT_SIGMA = 6.0
REJECT_FLOOR = 0.02
_CHANNELS = 3


def half_diagonal(image_size: tuple[int, int]) -> float:
    """Lensfun's vignetting unit: ``hypot((W - 1) / 2, (H - 1) / 2)`` pixels."""
    width, height = image_size
    return math.hypot((width - 1) / 2.0, (height - 1) / 2.0)


def _monomials(degree: int) -> list[tuple[int, int]]:
    """Exponents ``(i, j)`` of ``u^i v^j`` with ``1 <= i + j <= degree``."""
    return [(total - j, j) for total in range(1, degree + 1) for j in range(total + 1)]


def _smooth_basis(u: NDArray, v: NDArray, degree: int) -> NDArray:
    if not degree:
        return np.zeros(np.shape(u) + (0,))
    return np.stack([u**i * v**j for i, j in _monomials(degree)], axis=-1)


def _radial(r2: NDArray, k: NDArray) -> NDArray:
    """``V = 1 + k1 r^2 + k2 r^4 + k3 r^6`` (``k`` ``(3,)`` or ``(C, 3)`` against ``r2`` ``(..., 1)``)."""
    k = np.asarray(k)
    return 1.0 + r2 * (k[..., 0] + r2 * (k[..., 1] + r2 * k[..., 2]))


def _gain(u: NDArray, v: NDArray, k: NDArray, smooth: NDArray, degree: int) -> NDArray:
    gain = _radial((u * u + v * v)[..., None], k)
    if degree:
        gain = gain * np.exp(_smooth_basis(u, v, degree) @ np.asarray(smooth).T)
    return gain


@dataclass(frozen=True)
class FlatField:
    """A fitted flat field (see the module docstring for the model).

    Attributes
    ----------
    image_size : (int, int)
        ``(W, H)`` of the images it was fitted on.
    centre : (2,) ndarray
        The optical centre in pixels.
    k : (3, 3) ndarray
        ``k1 k2 k3`` of ``V`` per channel (rows R, G, B).
    smooth_degree : int
        Degree of the non-radial term (0: none).
    smooth : (3, n) ndarray
        Its coefficients per channel, for ``u^i v^j`` ordered by total degree, then by ``j``.
    residual_rms : (3,) ndarray
        RMS of the inlier samples' relative residuals per channel (0.01 is 1 %).
    gain_sigma_max : (3,) ndarray
        Largest standard deviation of ``G_c`` over the frame (relative), from the samples' noise.
    n_samples, n_rejected : int
        Samples used and rejected as outliers (background, dust, a patch read wrong).
    source : str
        ``grey card`` or ``neutral patches``.
    """

    image_size: tuple[int, int]
    centre: NDArray[np.float64]
    k: NDArray[np.float64]
    smooth_degree: int = 0
    smooth: NDArray[np.float64] = field(default_factory=lambda: np.zeros((_CHANNELS, 0)))
    residual_rms: NDArray[np.float64] = field(default_factory=lambda: np.zeros(_CHANNELS))
    gain_sigma_max: NDArray[np.float64] = field(default_factory=lambda: np.zeros(_CHANNELS))
    n_samples: int = 0
    n_rejected: int = 0
    source: str = "grey card"

    def _scaled(self, image_size: tuple[int, int]) -> tuple[NDArray, float]:
        """The centre and unit for an image of ``image_size`` (the same frame at another resolution)."""
        width, height = self.image_size
        if tuple(image_size) == (width, height):
            return np.asarray(self.centre, dtype=np.float64), half_diagonal(self.image_size)
        if abs(image_size[0] * height / (image_size[1] * width) - 1.0) > 0.01:
            raise CamcalError(f"the flat field is for {width}x{height} images; an image of {image_size[0]}x"
                              f"{image_size[1]} has another aspect ratio")
        scale = np.array([image_size[0] / width, image_size[1] / height])
        # the same physical radius: the fit's unit scaled with the image (pixel centres at integers)
        return (np.asarray(self.centre) + 0.5) * scale - 0.5, half_diagonal(self.image_size) * math.sqrt(scale.prod())

    def gain_at(self, xy: NDArray, image_size: tuple[int, int] | None = None) -> NDArray[np.float64]:
        """``G`` at pixels ``xy`` ``(N, 2)`` of an image of ``image_size`` (default: the fit's): ``(N, 3)``.

        Examples
        --------
        >>> flat = FlatField((641, 481), np.array([320.0, 240.0]), np.tile([-0.3, 0.0, 0.0], (3, 1)))
        >>> flat.gain_at(np.array([[320.0, 240.0], [0.0, 0.0]])).round(3).tolist()  # the centre, a corner (r = 1)
        [[1.0, 1.0, 1.0], [0.7, 0.7, 0.7]]
        """
        centre, unit = self._scaled(image_size or self.image_size)
        d = (np.asarray(xy, dtype=np.float64) - centre) / unit
        return _gain(d[:, 0], d[:, 1], self.k, self.smooth, self.smooth_degree)

    def gain(self, image_size: tuple[int, int] | None = None) -> NDArray[np.float32]:
        """The gain image ``(H, W, 3)`` float32 (1 at the optical centre)."""
        width, height = image_size or self.image_size
        centre, unit = self._scaled((width, height))
        u = np.broadcast_to(((np.arange(width) - centre[0]) / unit)[None, :], (height, width))
        v = np.broadcast_to(((np.arange(height) - centre[1]) / unit)[:, None], (height, width))
        return _gain(u, v, self.k, self.smooth, self.smooth_degree).astype(np.float32)

    def summary(self) -> str:
        """One line: source, centre, the darkest corner, residual and the gain's uncertainty."""
        width, height = self.image_size
        corners = np.array([[0, 0], [width - 1, 0], [0, height - 1], [width - 1, height - 1]], dtype=np.float64)
        low = self.gain_at(corners).min(axis=0)
        return (f"flat field from {self.source}: {self.n_samples} samples ({self.n_rejected} rejected), optical "
                f"centre {self.centre[0]:.1f}, {self.centre[1]:.1f} px, darkest corner R G B "
                f"{' '.join(f'{value:.3f}' for value in low)}; residual RMS "
                f"{100 * float(np.max(self.residual_rms)):.2f} %, gain sigma <= "
                f"{100 * float(np.max(self.gain_sigma_max)):.2f} %")

    def to_dict(self) -> dict[str, Any]:
        """The file's content (``format``, ``version``, the model and its quality)."""
        return {
            "format": FORMAT, "version": FORMAT_VERSION, "source": self.source,
            "image_size": [int(self.image_size[0]), int(self.image_size[1])],
            "model": {"radial": "pa", "radius_unit": "half diagonal", "centre_px": [float(c) for c in self.centre],
                      "k": [[float(v) for v in row] for row in self.k], "smooth_degree": int(self.smooth_degree),
                      "smooth": [[float(v) for v in row] for row in self.smooth]},
            "channels": ["R", "G", "B"],
            "residual_rms": [float(v) for v in self.residual_rms],
            "gain_sigma_max": [float(v) for v in self.gain_sigma_max],
            "n_samples": int(self.n_samples), "n_rejected": int(self.n_rejected),
        }

    @classmethod
    def from_dict(cls, data: Any) -> FlatField:
        """A flat field from :meth:`to_dict`'s content, every field checked (unknown keys refused)."""
        keys_field(data, "flat field", ("format", "version", "image_size", "model"),
                   ("source", "channels", "residual_rms", "gain_sigma_max", "n_samples", "n_rejected"))
        if data["format"] != FORMAT:
            raise CamcalError(f"flat field: format {data['format']!r} is not {FORMAT!r}")
        version = integer_field(data["version"], "version", 1)
        if version > FORMAT_VERSION:
            raise CamcalError(f"flat field: version {version} is newer than this camcal reads ({FORMAT_VERSION})")
        size = vector_field(data["image_size"], "image_size", 2)
        if not all(float(s).is_integer() and 2 <= s <= 1e6 for s in size):
            raise CamcalError(f"image_size: expected two integers from 2 to 1e6, got {data['image_size']!r}")
        model = keys_field(data["model"], "model", ("radial", "centre_px", "k"),
                           ("radius_unit", "smooth_degree", "smooth"))
        string_field(model["radial"], "model.radial", ("pa",))
        string_field(model.get("radius_unit", "half diagonal"), "model.radius_unit", ("half diagonal",))
        degree = integer_field(model.get("smooth_degree", 0), "model.smooth_degree", 0)
        if degree > 4:
            raise CamcalError(f"model.smooth_degree: expected 0 to 4, got {degree}")
        n_smooth = len(_monomials(degree))
        smooth = (np.array(matrix_field(model.get("smooth"), "model.smooth", _CHANNELS, n_smooth)) if n_smooth
                  else np.zeros((_CHANNELS, 0)))
        if "channels" in data and data["channels"] != ["R", "G", "B"]:
            raise CamcalError(f"channels: expected ['R', 'G', 'B'], got {data['channels']!r}")

        def triple(key: str) -> NDArray:
            if key not in data:
                return np.zeros(_CHANNELS)
            return np.array([number_field(v, f"{key}[{i}]", 0.0)
                             for i, v in enumerate(vector_field(data[key], key, _CHANNELS))])

        flat = cls((int(size[0]), int(size[1])), np.array(vector_field(model["centre_px"], "model.centre_px", 2)),
                   np.array(matrix_field(model["k"], "model.k", _CHANNELS, 3)), degree, smooth,
                   triple("residual_rms"), triple("gain_sigma_max"),
                   integer_field(data.get("n_samples", 0), "n_samples"),
                   integer_field(data.get("n_rejected", 0), "n_rejected"),
                   string_field(data.get("source", "grey card"), "source"))
        with np.errstate(over="ignore", invalid="ignore"):
            gain = _frame_gain(flat)
        if not np.all(np.isfinite(gain) & (gain < 1e3)):
            raise CamcalError("flat field: its gain is not finite or above 1000 somewhere in the frame")
        low = float(gain.min())
        if not low > 0.0:
            raise CamcalError(f"flat field: its gain falls to {low:.3g} inside the frame (must stay > 0)")
        return flat


def _frame_points(image_size: tuple[int, int], n: int = 33) -> NDArray:
    """An ``n`` x ``n`` grid of pixel positions over the frame, corners included: ``(n * n, 2)``."""
    width, height = image_size
    gx, gy = np.meshgrid(np.linspace(0, width - 1, n), np.linspace(0, height - 1, n))
    return np.column_stack([gx.ravel(), gy.ravel()])


def _frame_gain(flat: FlatField) -> NDArray:
    return flat.gain_at(_frame_points(flat.image_size))


def correct_flat_field(image: NDArray, flat: FlatField) -> NDArray:
    """A linear ``(H, W, 3)`` image divided by the flat field's gain (the falloff removed); a new array."""
    image = np.asarray(image)
    check_image(image, "image")
    return image / flat.gain((image.shape[1], image.shape[0])).astype(np.result_type(image.dtype, np.float32))


def apply_vignetting(image: NDArray, flat: FlatField) -> NDArray:
    """The inverse of :func:`correct_flat_field`: a linear ``(H, W, 3)`` image multiplied by the gain."""
    image = np.asarray(image)
    check_image(image, "image")
    return image * flat.gain((image.shape[1], image.shape[0])).astype(np.result_type(image.dtype, np.float32))


def fit_flat_field(samples: FlatFieldSamples, *, smooth_degree: int = 0, fit_centre: bool = True,
                   source: str = "grey card") -> FlatField:
    """Fit the flat field to samples (see the module docstring).

    Parameters
    ----------
    samples : FlatFieldSamples
    smooth_degree : int
        Degree of the non-radial term (0 to 4; 0: radial only).
    fit_centre : bool
        Fit the optical centre (else the image centre).
    source : str
        What the samples are, for the record.

    Returns
    -------
    FlatField

    Raises
    ------
    CamcalError
        Too few samples for the model, samples that do not reach ``MIN_REACH`` of the half diagonal, or a
        fitted gain that falls near 0 in the frame.
    """
    if not 0 <= smooth_degree <= 4:
        raise CamcalError(f"the smooth degree must be 0 to 4, got {smooth_degree}")
    width, height = samples.image_size
    layout = _Layout(fit_centre, np.array([(width - 1) / 2.0, (height - 1) / 2.0]), half_diagonal(samples.image_size),
                     int(samples.shot.max()) + 1, int(samples.patch.max()) + 1, smooth_degree)
    if len(samples.xy) * _CHANNELS < 3 * layout.n_params:
        raise CamcalError(f"too few samples for a flat field: {len(samples.xy)} positions for {layout.n_params} "
                          "parameters (3 values per parameter needed)")
    reach = float(np.max(np.hypot(*(samples.xy - layout.image_centre).T)) / layout.unit)
    if reach < MIN_REACH:
        raise CamcalError(f"the samples reach {reach:.2f} of the half diagonal from the centre, less than "
                          f"{MIN_REACH}: the corners would be extrapolated; fill more of the frame")
    log_values = np.log(samples.RGB)
    x = _initial(samples, log_values, layout)
    # first the middle of the frame (a card is there; what surrounds it is at the edges, where a free falloff
    # could bend to it), then everything from there
    middle = np.hypot(*(samples.xy - layout.image_centre).T) / layout.unit < MIDDLE
    if middle.sum() * _CHANNELS >= 3 * layout.n_params and np.all(np.isin(np.arange(layout.n_shots),
                                                                           samples.shot[middle])):
        x = _fit(samples.subset(middle), log_values[middle], x, layout, robust=True).x
    x = _fit(samples, log_values, x, layout, robust=True).x
    residual = layout.residuals(x, samples, log_values)
    scale = max(1.0, 1.4826 * float(np.median(np.abs(residual / samples.sigma))))
    inliers = ~np.any(np.abs(residual) > np.maximum(REJECT_SIGMA * scale * samples.sigma, REJECT_FLOOR), axis=1)
    if inliers.sum() * _CHANNELS < 3 * layout.n_params:
        raise CamcalError(f"too few samples agree with a smooth falloff: {int(inliers.sum())} of {len(inliers)} "
                          "(is the card uniform and evenly lit?)")
    for what, index, count in (("image", samples.shot, layout.n_shots), ("patch", samples.patch, layout.n_patches)):
        lost = sorted(set(range(count)) - set(index[inliers].tolist()))
        if lost:
            raise CamcalError(f"no sample of {what} {lost[0] + 1} agrees with the others' smooth falloff")
    result = _fit(samples.subset(inliers), log_values[inliers], x, layout)
    residual = layout.residuals(result.x, samples, log_values)
    flat = layout.flat(result.x, samples.image_size)
    gain = _frame_gain(flat)
    low = float(gain.min()) if np.all(np.isfinite(gain)) else 0.0
    if not (low > 0.05 and gain.max() < 1e3):
        raise CamcalError(f"the fitted falloff reaches {low:.3g} inside the frame: the samples do not hold a "
                          "lens's vignetting (fill more of the frame, or lower the smooth degree)")
    relative = np.expm1(residual[inliers])
    return replace(flat, residual_rms=np.sqrt(np.mean(relative**2, axis=0)),
                   gain_sigma_max=_gain_sigma(result, int(inliers.sum()) * _CHANNELS, layout, samples.image_size),
                   n_samples=int(inliers.sum()), n_rejected=int((~inliers).sum()), source=source)


@dataclass(frozen=True)
class _Layout:
    """Where each parameter sits in the fit's vector ``x``: the centre (when fitted), ``k`` ``(3, 3)``, the log
    exposure of each shot but the first ``(S - 1,)``, the log value of each patch ``(P, 3)``, the smooth term
    ``(3, n)``."""

    fit_centre: bool
    image_centre: NDArray
    unit: float
    n_shots: int
    n_patches: int
    degree: int

    @property
    def n_smooth(self) -> int:
        return len(_monomials(self.degree))

    @property
    def n_params(self) -> int:
        return 2 * self.fit_centre + self.n_shots - 1 + _CHANNELS * (3 + self.n_patches + self.n_smooth)

    def unpack(self, x: NDArray):
        """``x`` -> centre, ``k`` ``(3, 3)``, log exposures ``(S, 1)``, log patch values ``(P, 3)``, smooth
        ``(3, n)``."""
        i = 2 if self.fit_centre else 0
        centre = x[:2] if self.fit_centre else self.image_centre
        k = x[i : i + 9].reshape(_CHANNELS, 3)
        i += 9
        log_shot = np.concatenate([[0.0], x[i : i + self.n_shots - 1]])[:, None]
        i += self.n_shots - 1
        log_patch = x[i : i + _CHANNELS * self.n_patches].reshape(self.n_patches, _CHANNELS)
        i += _CHANNELS * self.n_patches
        smooth = x[i:].reshape(_CHANNELS, self.n_smooth)
        return centre, k, log_shot, log_patch, smooth

    def log_gain(self, x: NDArray, xy: NDArray) -> NDArray:
        """``log G`` at ``xy`` ``(N, 2)``: ``(N, 3)``."""
        centre, k, _, _, smooth = self.unpack(x)
        d = (xy - centre) / self.unit
        log_G = np.log(np.maximum(_radial(np.sum(d**2, axis=1)[:, None], k), 1e-6))
        if self.degree:
            log_G = log_G + _smooth_basis(d[:, 0], d[:, 1], self.degree) @ smooth.T
        return log_G

    def residuals(self, x: NDArray, samples: FlatFieldSamples, log_values: NDArray) -> NDArray:
        """``log value - log model`` ``(N, 3)``."""
        _, _, log_shot, log_patch, _ = self.unpack(x)
        return log_values - log_shot[samples.shot] - log_patch[samples.patch] - self.log_gain(x, samples.xy)

    def jacobian(self, x: NDArray, samples: FlatFieldSamples) -> NDArray:
        """``d residuals / d x``: ``(N * 3, n_params)``, rows in the order of ``residuals(...).ravel()``."""
        centre, k, _, _, smooth = self.unpack(x)
        n = len(samples.xy)
        d = (samples.xy - centre) / self.unit
        r2 = np.sum(d**2, axis=1)[:, None]
        V = np.maximum(_radial(r2, k), 1e-6)
        J = np.zeros((n, _CHANNELS, self.n_params))
        column = 0
        if self.fit_centre:
            dV_dr2 = k[:, 0] + r2 * (2.0 * k[:, 1] + 3.0 * k[:, 2] * r2)
            for j in range(2):
                J[:, :, j] = dV_dr2 / V * (2.0 * d[:, j : j + 1] / self.unit)
                if self.degree:
                    exponents = np.array(_monomials(self.degree))
                    power = exponents[:, j]
                    lowered = exponents - np.eye(2, dtype=int)[j]
                    dB = power * np.prod(d[:, None, :] ** np.maximum(lowered, 0)[None], axis=2)  # (N, n)
                    J[:, :, j] += dB @ smooth.T / self.unit
            column = 2
        for c in range(_CHANNELS):
            J[:, c, column + 3 * c : column + 3 * c + 3] = -np.hstack([r2, r2**2, r2**3]) / V[:, c : c + 1]
        column += 9
        shots = np.eye(self.n_shots)[samples.shot][:, 1:]
        J[:, :, column : column + self.n_shots - 1] = -shots[:, None, :]
        column += self.n_shots - 1
        patches = np.eye(self.n_patches)[samples.patch]
        for c in range(_CHANNELS):
            J[:, c, column + c : column + _CHANNELS * self.n_patches : _CHANNELS] = -patches
        column += _CHANNELS * self.n_patches
        if self.degree:
            basis = _smooth_basis(d[:, 0], d[:, 1], self.degree)
            for c in range(_CHANNELS):
                J[:, c, column + c * self.n_smooth : column + (c + 1) * self.n_smooth] = -basis
        return J.reshape(n * _CHANNELS, self.n_params)

    def flat(self, x: NDArray, image_size: tuple[int, int]) -> FlatField:
        centre, k, _, _, smooth = self.unpack(x)
        return FlatField((int(image_size[0]), int(image_size[1])), np.array(centre, dtype=np.float64),
                         np.array(k), self.degree, np.array(smooth))


def _initial(samples: FlatFieldSamples, log_values: NDArray, layout: _Layout) -> NDArray:
    """Start: the image centre, no falloff, each patch at its median, each shot at its median ratio to the first."""
    log_patch = np.array([np.median(log_values[samples.patch == p], axis=0) for p in range(layout.n_patches)])
    log_shot = np.array([np.median((log_values - log_patch[samples.patch])[samples.shot == s])
                         for s in range(layout.n_shots)])
    parts = [layout.image_centre] if layout.fit_centre else []
    parts += [np.zeros(9), log_shot[1:] - log_shot[0], log_patch.ravel() + log_shot[0],
              np.zeros(_CHANNELS * layout.n_smooth)]
    return np.concatenate(parts)


def _fit(samples: FlatFieldSamples, log_values: NDArray, x0: NDArray, layout: _Layout, robust: bool = False):
    """The model's least squares (Levenberg-Marquardt), residuals in units of each sample's sigma.

    ``robust``: iteratively reweighted with Cauchy weights ``1 / (1 + (z / f)^2)`` per sample, ``z`` its largest
    residual over the channels, ``f`` their robust scale (at least 3 sigma), until no residual moves by 0.01 sigma (at most 12 rounds of at most 25
    evaluations: the weights need the model's values, which settle early, not its parameters, which with a
    smooth term trade the centre against the tilt along a flat valley; the plain fit that follows converges).
    """
    inverse_sigma = 1.0 / samples.sigma.ravel()

    def weighted(x: NDArray) -> NDArray:
        return layout.residuals(x, samples, log_values).ravel() * inverse_sigma

    def jacobian(x: NDArray) -> NDArray:
        return layout.jacobian(x, samples) * inverse_sigma[:, None]

    if not robust:
        return scipy.optimize.least_squares(weighted, x0, jac=jacobian, method="lm", x_scale="jac")
    z = weighted(x0)
    for _ in range(12):
        # one weight per sample, from its worst channel: a surface that matches the card in one channel only
        # (a grey wall beside a warm card) is not the card in any
        worst = np.max(np.abs(z.reshape(-1, _CHANNELS)), axis=1)
        f_scale = max(3.0, 1.4826 * float(np.median(worst)))
        root_weight = np.repeat(1.0 / np.sqrt(1.0 + (worst / f_scale) ** 2), _CHANNELS)
        result = scipy.optimize.least_squares(lambda p: weighted(p) * root_weight, x0, method="lm", x_scale="jac",
                                              jac=lambda p: jacobian(p) * root_weight[:, None], max_nfev=25)
        x0, previous, z = result.x, z, weighted(result.x)
        if np.max(np.abs(z - previous)) < 0.01:
            break
    return result


def _gain_sigma(result, n_values: int, layout: _Layout, image_size: tuple[int, int]) -> NDArray:
    """The largest standard deviation of ``G_c`` (relative) over a 17 x 17 grid of the frame, per channel.

    First order: ``var log G = g^T C g``, ``g`` the gradient of ``log G`` in the parameters (central
    differences), ``C = s^2 (J^T J)^-1`` of the final fit with ``s^2`` from its residual.
    """
    J = result.jac
    covariance = np.linalg.pinv(J.T @ J) * (2.0 * result.cost / max(n_values - J.shape[1], 1))
    xy = _frame_points(image_size, 17)
    steps = 1e-6 * np.maximum(np.abs(result.x), 1.0)
    g = np.stack([(layout.log_gain(result.x + np.eye(len(steps))[i] * steps[i], xy)
                   - layout.log_gain(result.x - np.eye(len(steps))[i] * steps[i], xy)) / (2 * steps[i])
                  for i in range(len(steps))], axis=-1)  # (M, 3, n_params)
    variance = np.einsum("mci,ij,mcj->mc", g, covariance, g)
    return np.sqrt(np.max(np.maximum(variance, 0.0), axis=0))


@dataclass(frozen=True)
class RadialTerms:
    """One ``pa`` term set for every channel (what Lensfun's vignetting entry holds).

    Attributes
    ----------
    k : (3,) ndarray
        ``k1 k2 k3`` fitted to the mean of the channels' ``V_c``.
    centre : (2,) ndarray
        The optical centre in pixels.
    max_deviation : float
        Largest ``|G_c / V - 1|`` over the frame: the colour shading and non-radial falloff it does not hold.
    """

    k: NDArray[np.float64]
    centre: NDArray[np.float64]
    max_deviation: float


def common_radial_terms(flat: FlatField, centre: NDArray | None = None) -> RadialTerms:
    """The ``pa`` terms of the channels' mean gain (least squares over a 33 x 33 grid of the frame) about
    ``centre`` (default: the flat field's optical centre), and what they miss.

    Lensfun's ``pa`` vignetting multiplies every channel by one factor about
    the lens' one centre (its distortion's too); a flat field with colour
    shading, a non-radial term or another centre holds more than it.
    """
    centre = np.asarray(flat.centre if centre is None else centre, dtype=np.float64)
    xy = _frame_points(flat.image_size)
    r2 = np.sum(((xy - centre) / half_diagonal(flat.image_size)) ** 2, axis=1)
    gain = flat.gain_at(xy)
    k, *_ = np.linalg.lstsq(np.column_stack([r2, r2**2, r2**3]), gain.mean(axis=1) - 1.0, rcond=None)
    deviation = float(np.max(np.abs(gain / _radial(r2, k)[:, None] - 1.0)))
    return RadialTerms(k, centre, deviation)
