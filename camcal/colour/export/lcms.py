"""LittleCMS 2 through ctypes: an independent reader of camcal's ICC profiles.

Pillow's ``ImageCms`` wraps LittleCMS but only for 8-bit images; checking a
profile against ``fit.apply`` needs doubles, so this calls ``cmsDoTransform``
of the same library (the system's ``liblcms2``, else the copy Pillow bundles)
with ``TYPE_RGB_DBL`` -> ``TYPE_XYZ_DBL`` (lcms2.h pixel-format macros).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import glob
import os
from typing import Any

import numpy as np

from camcal.base.errors import CamcalError

__all__ = ["load_lcms", "lcms_to_XYZ"]

TYPE_RGB_DBL = (1 << 22) | (4 << 16) | (3 << 3)   # lcms2.h: FLOAT_SH(1)|COLORSPACE_SH(PT_RGB)|CHANNELS_SH(3)
TYPE_XYZ_DBL = (1 << 22) | (9 << 16) | (3 << 3)   # PT_XYZ = 9
INTENT_RELATIVE_COLORIMETRIC = 1


def load_lcms() -> Any | None:
    """LittleCMS 2: the system library, else the copy Pillow bundles; ``None`` when neither loads."""
    candidates = []
    name = ctypes.util.find_library("lcms2")
    if name:
        candidates.append(name)
    try:
        import PIL  # noqa: PLC0415

        candidates += glob.glob(os.path.join(os.path.dirname(PIL.__file__), os.pardir, "pillow.libs", "liblcms2*"))
    except ImportError:
        pass
    for candidate in candidates:
        try:
            lib = ctypes.CDLL(candidate)
        except OSError:
            continue
        lib.cmsOpenProfileFromMem.restype = ctypes.c_void_p
        lib.cmsOpenProfileFromMem.argtypes = [ctypes.c_char_p, ctypes.c_uint32]
        lib.cmsCreateXYZProfile.restype = ctypes.c_void_p
        lib.cmsCreateTransform.restype = ctypes.c_void_p
        lib.cmsCreateTransform.argtypes = [ctypes.c_void_p, ctypes.c_uint32, ctypes.c_void_p, ctypes.c_uint32,
                                           ctypes.c_uint32, ctypes.c_uint32]
        lib.cmsDoTransform.argtypes = [ctypes.c_void_p, ctypes.c_void_p, ctypes.c_void_p, ctypes.c_uint32]
        lib.cmsDeleteTransform.argtypes = [ctypes.c_void_p]
        lib.cmsCloseProfile.argtypes = [ctypes.c_void_p]
        return lib
    return None


def lcms_to_XYZ(lib: Any, profile: bytes, codes: Any) -> np.ndarray:
    """LittleCMS: device RGB ``(N, 3)`` doubles in [0, 1] -> PCS XYZ D50 (Y = 1), relative colorimetric.

    Raises :class:`CamcalError` when LittleCMS cannot open the profile or build the transform.
    """
    src = lib.cmsOpenProfileFromMem(profile, len(profile))
    if not src:
        raise CamcalError("LittleCMS could not open the profile")
    dst = lib.cmsCreateXYZProfile()
    transform = lib.cmsCreateTransform(src, TYPE_RGB_DBL, dst, TYPE_XYZ_DBL, INTENT_RELATIVE_COLORIMETRIC, 0)
    if not transform:
        lib.cmsCloseProfile(src)
        lib.cmsCloseProfile(dst)
        raise CamcalError("LittleCMS could not build a transform from the profile")
    inp = np.ascontiguousarray(codes, dtype=np.float64)
    out = np.zeros_like(inp)
    lib.cmsDoTransform(transform, inp.ctypes.data, out.ctypes.data, inp.shape[0])
    lib.cmsDeleteTransform(transform)
    lib.cmsCloseProfile(src)
    lib.cmsCloseProfile(dst)
    return out
