"""A camera's input transform as a DaVinci Resolve DCTL, its numbers inlined.

:func:`dctl_text` writes the ``transform`` function Resolve calls per pixel
(``__DEVICE__ float3 transform(int p_Width, int p_Height, int p_X, int
p_Y, float p_R, float p_G, float p_B)``) for the input transform of
:func:`camcal.colour.export.aces.input_transform`: each channel's
linearisation, then the fit's own model, exactly (no bake): its terms of
linear camera RGB (``R``, ``R*G``, ``(R*G)^(1/2)``..., root terms with the
sign-preserving power ``copysign(|x|^(1/d), x)`` as camcal evaluates them,
:func:`camcal.colour.fit.terms.expand`) and one matrix, the model's
coefficients times the matrix from the fit's XYZ to the ACES space, so a
``matrix3x3``, ``polynomial`` or ``root-polynomial`` fit is the same
arithmetic as camcal's. (An RBF fit has no such form: its CLF holds the
baked Lut3D.) A transform to ACES2065-1 starts with
``DEFINE_ACES_PARAM(IS_PARAMETRIC_ACES_TRANSFORM: 0)``, the line that lets
Resolve list the file as an ACES Input Transform (folder ``ACES
Transforms/IDT``); without it (ACEScg) it is a DCTL LUT.

The linearisations, as camcal applies them
(:class:`camcal.colour.chart.linearise.ChannelCurve`): ``none`` is the
identity; ``gamma-offset`` ``gain * pow(max(v - offset, 0), gamma)``;
``lut1d`` its samples as a ``__CONSTANT__`` array, linearly interpolated on
the uniform grid over [0, 1] and extended linearly beyond both ends; a
``named`` curve sampled at 4096 code values the same way (its largest
relative error is the input transform's ``linearisation_error``).

The emitted code is a small subset of DCTL (C with Resolve's
``__DEVICE__``, ``__CONSTANT__``, ``float3``, ``make_float3``, ``_powf``,
``_fmaxf``, ``_fminf``, ``_floorf``, ``_fabs``, ``_copysignf``): constant arrays, one function per
channel and ``const`` declarations of sums of products, so that it reads
(and can be checked) line by line.

References
----------
- Blackmagic Design, DaVinci Resolve DCTL reference (README.txt of the
  Developer/DaVinciCTL folder): the ``transform`` entry point, the math
  functions, ACES DCTL transforms (``DEFINE_ACES_PARAM``).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from camcal.base.errors import CamcalError
from camcal.colour.chart.linearise import ChannelCurve
from camcal.colour.export.aces import InputTransform
from camcal.colour.export.ocio_config import CURVE_SAMPLES
from camcal.colour.fit.models import LinearTermsModel
from camcal.colour.fit.terms import parse_term

__all__ = ["dctl_float", "dctl_text"]

_CHANNELS = ("r", "g", "b")
_INPUTS = ("p_R", "p_G", "p_B")


def dctl_float(value: float) -> str:
    """A C ``float`` literal that round-trips a float32 (9 significant digits).

    Examples
    --------
    >>> dctl_float(1.0), dctl_float(-0.5), dctl_float(1e-7)
    ('1.0f', '-0.5f', '1.00000001e-07f')
    """
    value = float(np.float32(value))
    if not np.isfinite(value):
        raise CamcalError(f"cannot write a non-finite number ({value}) into a DCTL")
    text = f"{value:.9g}"
    if not any(c in text for c in ".e"):
        text += ".0"
    return text + "f"


def _array(name: str, values: Sequence[float]) -> list[str]:
    numbers = [dctl_float(v) for v in values]
    rows = [", ".join(numbers[i : i + 8]) for i in range(0, len(numbers), 8)]
    return [f"__CONSTANT__ float {name}[{len(numbers)}] = {{", *(f"    {row}," for row in rows[:-1]),
            f"    {rows[-1]}", "};"]


def _curve(channel: str, curve: ChannelCurve) -> tuple[list[str], list[str]]:
    """The constant array (if any) and the function ``linearise_<channel>(float v)`` of one curve."""
    head = [f"__DEVICE__ float linearise_{channel}(float v)", "{"]
    if curve.kind == "none":
        return [], [*head, "    return v;", "}"]
    if curve.kind == "gamma-offset":
        p = curve.params
        return [], [*head, f"    return {dctl_float(p['gain'])} * _powf(_fmaxf(v - {dctl_float(p['offset'])}, 0.0f), "
                           f"{dctl_float(p['gamma'])});", "}"]
    samples = (np.asarray(curve.params["samples"]) if curve.kind == "lut1d"
               else curve.apply(np.linspace(0.0, 1.0, CURVE_SAMPLES)))
    name, last = f"LINEARISE_{channel.upper()}", samples.size - 1
    body = [f"    const float x = v * {dctl_float(last)};",
            f"    const float i = _fminf(_fmaxf(_floorf(x), 0.0f), {dctl_float(last - 1)});",
            "    const int k = (int)i;",
            f"    return {name}[k] + (x - i) * ({name}[k + 1] - {name}[k]);"]
    return _array(name, samples), [*head, *body, "}"]


def _term(index: int, term: str) -> list[str]:
    """``const float t<index> = ...;`` of one model term of ``r``, ``g``, ``b`` (a root term in two lines)."""
    exponents, root = parse_term(term)
    factors = [c for c, e in zip(_CHANNELS, exponents) for _ in range(e)]
    product = " * ".join(factors) or "1.0f"
    if not root or len(factors) <= 1:
        return [f"    const float t{index} = {product};"]
    return [f"    const float p{index} = {product};",
            f"    const float t{index} = _copysignf(_powf(_fabs(p{index}), {dctl_float(1.0 / len(factors))}), "
            f"p{index});"]


def dctl_text(transform: InputTransform) -> str:
    """The input transform as a DaVinci Resolve DCTL.

    Parameters
    ----------
    transform
        The input transform of a ``matrix3x3``, ``polynomial`` or
        ``root-polynomial`` fit.

    Returns
    -------
    str
        The DCTL source: a comment block naming the transform (ID, user
        name, description), the ACES parameter line for ACES2065-1, the
        linearisation's arrays and functions, then ``transform``: the
        linearised channels ``r, g, b``, the model's terms ``t0, t1...``
        and ``out = (M_out @ M) t``.

    Raises
    ------
    CamcalError
        An RBF model (no closed form here: use the CLF).
    """
    model = transform.model
    if not isinstance(model, LinearTermsModel):
        raise CamcalError(f"a DCTL holds matrix, polynomial and root-polynomial fits; this fit's model is "
                          f"{model.label}: use its CLF (the model baked as a Lut3D)")
    M = transform.output @ model.M
    lines = [f"// camcal: {transform.user_name}",
             f"// ACES transform ID: {transform.transform_id}",
             f"// {transform.description}",
             f"// Camera code values (0-1) -> per-channel linearisation -> {model.label} terms -> {transform.space}."]
    if transform.space == "ACES2065-1":
        lines += ["DEFINE_ACES_PARAM(IS_PARAMETRIC_ACES_TRANSFORM: 0)"]
    for channel, curve in zip(_CHANNELS, transform.linearisation.channels):
        arrays, function = _curve(channel, curve)
        lines += ["", *arrays, *([""] if arrays else []), *function]
    lines += ["", "__DEVICE__ float3 transform(int p_Width, int p_Height, int p_X, int p_Y, float p_R, float p_G, "
              "float p_B)", "{"]
    lines += [f"    const float {c} = linearise_{c}({p});" for c, p in zip(_CHANNELS, _INPUTS)]
    for index, term in enumerate(model.terms):
        lines += _term(index, term)
    for row, out in zip(M, ("out_r", "out_g", "out_b")):
        terms = " + ".join(f"{dctl_float(m)} * t{i}" for i, m in enumerate(row))
        lines.append(f"    const float {out} = {terms};")
    lines += ["    return make_float3(out_r, out_g, out_b);", "}"]
    return "\n".join(lines) + "\n"
