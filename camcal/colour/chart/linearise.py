"""Per-channel linearisation: camera code values to linear camera RGB.

Code values are normalised to ``[0, 1]`` (an 8-bit 255 is 1.0; a 16-bit
65535 is 1.0). Each channel has its own curve, one of:

``none``
    identity: the input is already linear (raw, linear EXR, simulated).
``gamma-offset``
    ``L = gain * max(V - offset, 0) ** gamma``, fitted to the neutral
    patches (relative error of the reference luminance Y).
``lut1d``
    a monotone curve sampled at ``n`` uniform code values on ``[0, 1]``,
    linearly interpolated, extended linearly beyond both ends. Fitted as the
    gamma-offset curve multiplied by a monotone (PCHIP) interpolation of its
    residual ratio at the neutral patches, so it passes through every
    neutral exactly and keeps the gamma shape between and beyond them.
``named``
    a known transfer function's decoding from colour-science's
    ``CCTF_DECODINGS`` (``sRGB``, ``ITU-R BT.709``, ``ARRI LogC3``,
    ``S-Log3``, ``V-Log``...), times a per-channel ``scale`` fitted to the
    neutral patches (white balance; 1 when no neutrals are given).

After a fit, the neutral patches come out with ``R = G = B = Y`` (their
reference luminance) up to the curve's residual.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from camcal.base.errors import CamcalError
from camcal.base.extras import require

__all__ = [
    "CURVE_KINDS",
    "NAMED_ALIASES",
    "ChannelCurve",
    "Linearisation",
    "named_function",
    "fit_linearisation",
]

CURVE_KINDS = ("none", "gamma-offset", "lut1d", "named")
LUT_SIZE = 256
NAMED_ALIASES = {
    "srgb": "sRGB",
    "rec709": "ITU-R BT.709",
    "bt709": "ITU-R BT.709",
    "rec.709": "ITU-R BT.709",
    "rec2020": "ITU-R BT.2020",
    "bt1886": "ITU-R BT.1886",
    "logc3": "ARRI LogC3",
    "logc4": "ARRI LogC4",
    "slog3": "S-Log3",
    "vlog": "V-Log",
    "clog3": "Canon Log 3",
    "redlog3g10": "Log3G10",
    "flog": "F-Log",
    "acescct": "ACEScct",
}


def named_function(name: str) -> str:
    """Canonical colour-science name of a transfer function (case-insensitive).

    Examples
    --------
    >>> named_function("rec709")
    'ITU-R BT.709'
    """
    colour = require("colour")

    key = str(name).strip()
    if key.lower() in NAMED_ALIASES:
        return NAMED_ALIASES[key.lower()]
    for canonical in colour.CCTF_DECODINGS:
        if canonical.lower() == key.lower():
            return canonical
    raise CamcalError(
        f"unknown transfer function {name!r}, expected one of colour-science's CCTF_DECODINGS "
        "(e.g. sRGB, ITU-R BT.709, ARRI LogC3, S-Log3, V-Log)"
    )


@dataclass(frozen=True, eq=False)
class ChannelCurve:
    """One channel's code-value-to-linear curve (see the module docstring).

    ``params`` by kind: ``none``: ``{}``; ``gamma-offset``: ``gamma``,
    ``offset``, ``gain``; ``lut1d``: ``samples`` (tuple of floats on a
    uniform grid over [0, 1]); ``named``: ``function``, ``scale``.
    """

    kind: str
    params: dict

    def __post_init__(self) -> None:
        if self.kind not in CURVE_KINDS:
            raise CamcalError(f"unknown linearisation {self.kind!r}, expected one of: {', '.join(CURVE_KINDS)}")
        params = dict(self.params)
        if self.kind == "lut1d":
            samples = tuple(float(v) for v in params.get("samples", ()))
            if len(samples) < 2:
                raise CamcalError("a lut1d linearisation needs at least 2 samples")
            if np.any(np.diff(samples) < 0):
                raise CamcalError("lut1d samples must be non-decreasing (a monotone curve)")
            params["samples"] = samples
        object.__setattr__(self, "params", params)

    def apply(self, V: Any) -> np.ndarray:
        """Linear values of normalised code values ``V`` (any shape)."""
        V = np.asarray(V, dtype=np.float64)
        p = self.params
        if self.kind == "none":
            return V.copy()
        if self.kind == "gamma-offset":
            return p["gain"] * np.maximum(V - p["offset"], 0.0) ** p["gamma"]
        if self.kind == "named":
            colour = require("colour")

            decode = colour.CCTF_DECODINGS[p["function"]]
            return p["scale"] * np.asarray(decode(V), dtype=np.float64)
        samples = np.asarray(p["samples"])
        x = np.linspace(0.0, 1.0, samples.size)
        out = np.interp(V, x, samples)
        step = x[1] - x[0]
        low_slope = (samples[1] - samples[0]) / step
        high_slope = (samples[-1] - samples[-2]) / step
        out = np.where(V < 0, samples[0] + V * low_slope, out)
        return np.where(V > 1, samples[-1] + (V - 1) * high_slope, out)

    def to_dict(self) -> dict:
        if self.kind == "none":
            return {"kind": "none"}
        if self.kind == "lut1d":
            return {"kind": "lut1d", "domain": [0.0, 1.0], "samples": [float(v) for v in self.params["samples"]]}
        if self.kind == "named":
            return {"kind": "named", "function": self.params["function"], "scale": float(self.params["scale"])}
        return {"kind": "gamma-offset", "gamma": float(self.params["gamma"]),
                "offset": float(self.params["offset"]), "gain": float(self.params["gain"])}

    @classmethod
    def from_dict(cls, data: dict) -> ChannelCurve:
        """From the checked ``to_dict`` form."""
        kind = data["kind"]
        if kind == "none":
            return cls("none", {})
        if kind == "lut1d":
            if list(data["domain"]) != [0.0, 1.0]:
                raise CamcalError("lut1d domain must be [0.0, 1.0]")
            return cls("lut1d", {"samples": data["samples"]})
        if kind == "named":
            return cls("named", {"function": named_function(data["function"]), "scale": data["scale"]})
        return cls("gamma-offset", {k: data[k] for k in ("gamma", "offset", "gain")})

    def __eq__(self, other: object) -> bool:
        return type(other) is type(self) and self.to_dict() == other.to_dict()  # type: ignore[attr-defined]

    __hash__ = None  # type: ignore[assignment]


@dataclass(frozen=True, eq=False)
class Linearisation:
    """Three channel curves, R, G, B; plus the RMS relative residual of the fit."""

    channels: tuple[ChannelCurve, ChannelCurve, ChannelCurve]
    residual: float | None = None

    @classmethod
    def identity(cls) -> Linearisation:
        return cls((ChannelCurve("none", {}),) * 3)

    @property
    def is_identity(self) -> bool:
        return all(c.kind == "none" for c in self.channels)

    @property
    def label(self) -> str:
        kinds = {c.kind for c in self.channels}
        if kinds == {"named"}:
            return f"named:{self.channels[0].params['function']}"
        return "/".join(sorted(kinds))

    def apply(self, codes: Any) -> np.ndarray:
        """Linear camera RGB ``(..., 3)`` of normalised code values ``(..., 3)``."""
        codes = np.asarray(codes, dtype=np.float64)
        if codes.shape[-1:] != (3,):
            raise CamcalError(f"code values must have shape (N, 3), got {codes.shape}")
        return np.stack([c.apply(codes[..., i]) for i, c in enumerate(self.channels)], axis=-1)

    def to_dict(self) -> dict:
        out: dict = {"channels": [c.to_dict() for c in self.channels]}
        if self.residual is not None:
            out["residual"] = float(self.residual)
        return out

    @classmethod
    def from_dict(cls, data: dict) -> Linearisation:
        channels = tuple(ChannelCurve.from_dict(c) for c in data["channels"])
        return cls(channels, data.get("residual"))  # type: ignore[arg-type]

    def __eq__(self, other: object) -> bool:
        return type(other) is type(self) and self.to_dict() == other.to_dict()  # type: ignore[attr-defined]

    __hash__ = None  # type: ignore[assignment]


def _fit_gamma_offset(V: np.ndarray, Y: np.ndarray) -> dict:
    from scipy.optimize import least_squares

    def model(p, v):
        return np.exp(p[0]) * np.maximum(v - p[2], 0.0) ** p[1]

    def residual(p):
        return (model(p, V) - Y) / Y

    gamma0 = 2.2
    gain0 = float(np.median(Y / np.maximum(V, 1e-6) ** gamma0))
    upper_offset = float(np.min(V)) - 1e-4
    p0 = np.array([np.log(max(gain0, 1e-9)), gamma0, min(0.0, upper_offset - 1e-4)])
    result = least_squares(
        residual, p0,
        bounds=([-50.0, 0.3, -0.5], [50.0, 5.0, upper_offset]),
    )
    return {"gamma": float(result.x[1]), "offset": float(result.x[2]), "gain": float(np.exp(result.x[0]))}


def _fit_lut(V: np.ndarray, Y: np.ndarray, base: ChannelCurve, n: int) -> ChannelCurve:
    from scipy.interpolate import PchipInterpolator

    order = np.argsort(V)
    V, Y = V[order], Y[order]
    ratio = np.log(Y / np.maximum(base.apply(V), 1e-12))
    unique_V, index = np.unique(V, return_index=True)
    ratio = ratio[index]
    x = np.linspace(0.0, 1.0, n)
    if unique_V.size >= 2:
        correction = PchipInterpolator(unique_V, ratio, extrapolate=False)(np.clip(x, unique_V[0], unique_V[-1]))
    else:
        correction = np.full(n, ratio[0])
    samples = base.apply(x) * np.exp(correction)
    samples = np.maximum.accumulate(samples)
    return ChannelCurve("lut1d", {"samples": tuple(float(s) for s in samples)})


def fit_linearisation(codes: Any, Y: Any, kind: str = "gamma-offset", *, lut_size: int = LUT_SIZE) -> Linearisation:
    """Fit per-channel curves mapping neutral patches' codes to their luminance.

    Parameters
    ----------
    codes
        ``(M, 3)`` normalised code values of the neutral patches.
    Y
        ``(M,)`` reference luminance of those patches (white Y = 1).
    kind
        ``"none"``, ``"gamma-offset"``, ``"lut1d"`` or ``"named:FUNCTION"``
        (e.g. ``"named:sRGB"``).
    lut_size
        Samples of a ``lut1d`` curve.

    Returns
    -------
    Linearisation
        With ``residual``, the RMS relative error ``(L - Y) / Y`` over the
        neutral patches and channels.
    """
    if kind == "none":
        return Linearisation.identity()
    codes = np.asarray(codes, dtype=np.float64)
    Y = np.asarray(Y, dtype=np.float64)
    if codes.ndim != 2 or codes.shape[1] != 3 or Y.shape != (codes.shape[0],):
        raise CamcalError(f"neutral codes (M, 3) and Y (M,) do not agree: {codes.shape}, {Y.shape}")
    if kind.startswith("named"):
        _, _, name = kind.partition(":")
        function = named_function(name or "sRGB")
        curves = []
        for ch in range(3):
            base = ChannelCurve("named", {"function": function, "scale": 1.0}).apply(codes[:, ch])
            ok = base > 0
            scale = float(np.sum(base[ok] * Y[ok]) / np.sum(base[ok] ** 2)) if np.any(ok) else 1.0
            curves.append(ChannelCurve("named", {"function": function, "scale": scale}))
        lin = Linearisation(tuple(curves))  # type: ignore[arg-type]
    else:
        if kind not in ("gamma-offset", "lut1d"):
            raise CamcalError(
                f"unknown linearisation {kind!r}, expected one of: none, gamma-offset, lut1d, named:FUNCTION"
            )
        good = np.all(codes > 0.5 / 255, axis=1) & np.all(codes < 254.5 / 255, axis=1) & (Y > 0)
        if np.count_nonzero(good) < 3:
            raise CamcalError(
                f"linearisation needs at least 3 unclipped neutral patches, got {np.count_nonzero(good)}"
            )
        curves = []
        for ch in range(3):
            base = ChannelCurve("gamma-offset", _fit_gamma_offset(codes[good, ch], Y[good]))
            curves.append(_fit_lut(codes[good, ch], Y[good], base, lut_size) if kind == "lut1d" else base)
        lin = Linearisation(tuple(curves))  # type: ignore[arg-type]
    L = lin.apply(codes)
    ok = Y > 0
    residual = float(np.sqrt(np.mean(((L[ok] - Y[ok, None]) / Y[ok, None]) ** 2)))
    return Linearisation(lin.channels, residual)
