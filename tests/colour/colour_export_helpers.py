"""Shared pieces of the colour export tests: fits of the simulated camera, LittleCMS via ctypes."""

import ctypes
import ctypes.util
import glob
import os

import numpy as np

from camcal.colour.characterise import characterise
from camcal.colour.patches import PatchSet

GAMMA = 2.2  # the simulated camera's encoding: code = linear ** (1 / 2.2)


def codes_of(RGB):
    return np.clip(RGB, 0.0, 1.0) ** (1.0 / GAMMA)


def make_fit(sim, model, linearise="gamma-offset", target_white=None, camera="nikon"):
    """A characterisation of the simulated Nikon from gamma-encoded code values."""
    train = PatchSet(sim.names_train, codes_of(sim.RGB_train), sim.XYZ_train)
    test = PatchSet(sim.names_test, codes_of(sim.RGB_test), sim.XYZ_test)
    return characterise(train, white="D65", model=model, linearise=linearise, test=test,
                        target_white=target_white, camera=camera, loo=False).fit


def code_grid(n=9):
    g = np.linspace(0.0, 1.0, n)
    return np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)


TYPE_RGB_DBL = (1 << 22) | (4 << 16) | (3 << 3)   # lcms2.h: FLOAT_SH(1)|COLORSPACE_SH(PT_RGB)|CHANNELS_SH(3)
TYPE_XYZ_DBL = (1 << 22) | (9 << 16) | (3 << 3)   # PT_XYZ = 9
INTENT_RELATIVE_COLORIMETRIC = 1


def load_lcms():
    """LittleCMS 2: the system library, else the copy Pillow bundles; None when neither loads."""
    candidates = []
    name = ctypes.util.find_library("lcms2")
    if name:
        candidates.append(name)
    try:
        import PIL

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


def lcms_to_XYZ(lib, profile: bytes, codes):
    """LittleCMS: device RGB (doubles in [0, 1]) -> PCS XYZ D50 (Y = 1), relative colorimetric."""
    src = lib.cmsOpenProfileFromMem(profile, len(profile))
    assert src, "LittleCMS could not open the profile"
    dst = lib.cmsCreateXYZProfile()
    transform = lib.cmsCreateTransform(src, TYPE_RGB_DBL, dst, TYPE_XYZ_DBL, INTENT_RELATIVE_COLORIMETRIC, 0)
    assert transform, "LittleCMS could not build a transform"
    inp = np.ascontiguousarray(codes, dtype=np.float64)
    out = np.zeros_like(inp)
    lib.cmsDoTransform(transform, inp.ctypes.data, out.ctypes.data, inp.shape[0])
    lib.cmsDeleteTransform(transform)
    lib.cmsCloseProfile(src)
    lib.cmsCloseProfile(dst)
    return out
