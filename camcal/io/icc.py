"""ICC profile files: a checked profile written atomically."""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

from camcal.base.atomic import atomic_path
from camcal.base.errors import CamcalError
from camcal.colour.bake.transforms import LUT_SIZES
from camcal.colour.export.icc import ICCProfile, check_icc, icc_profile_from_fit
from camcal.colour.fit.record import ColourFit

__all__ = ["write_icc", "export_icc"]


def write_icc(profile: ICCProfile, path: str | os.PathLike) -> Path:
    """Check the bytes, then write them atomically (temporary file + rename)."""
    check_icc(profile.data)
    path = Path(path)
    with atomic_path(path) as tmp:
        tmp.write_bytes(profile.data)
        if tmp.read_bytes() != profile.data:  # pragma: no cover - a failing disk
            raise CamcalError(f"writing {path} failed: the bytes read back differ")
    return path


def export_icc(fit: ColourFit, camera: str, path: str | os.PathLike, *, version: int = 4,
               max_delta_E: float = 0.2, lut_sizes: Sequence[int] = LUT_SIZES) -> ICCProfile:
    """Build, check and write the ICC profile of a characterisation; returns it."""
    profile = icc_profile_from_fit(fit, camera, version=version, max_delta_E=max_delta_E, lut_sizes=lut_sizes)
    write_icc(profile, path)
    return profile
