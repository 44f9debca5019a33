"""The ACES hand-off files of a characterisation: CLF, AMF 2.0 and DaVinci Resolve DCTL.

:func:`export_aces` builds the camera's input transform
(:func:`camcal.colour.export.aces.input_transform`) once and writes any of
its three files, each built before anything is written and then written
atomically: the CLF (:func:`camcal.colour.export.aces.clf_text`), the AMF
that names that CLF by its path relative to the AMF and its SHA-256
(:func:`camcal.colour.export.amf.amf_text`), and the DCTL
(:func:`camcal.colour.export.dctl.dctl_text`).
"""

from __future__ import annotations

import hashlib
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from camcal.base.atomic import atomic_path
from camcal.base.clock import utc_timestamp
from camcal.base.errors import CamcalError
from camcal.colour.bake.transforms import LUT_SIZES
from camcal.colour.export.aces import InputTransform, clf_text, input_transform
from camcal.colour.fit.record import ColourFit

__all__ = ["ACESExport", "build_aces", "export_aces"]


@dataclass(frozen=True)
class ACESExport:
    """The input transform, its files (``None``: not asked for) and their bytes (:meth:`write` writes them)."""

    transform: InputTransform
    clf: Path | None = None
    amf: Path | None = None
    dctl: Path | None = None
    applied: bool = False
    contents: tuple[tuple[Path, bytes], ...] = field(default=(), repr=False)

    def write(self) -> ACESExport:
        """Write each file atomically; returns itself."""
        for path, data in self.contents:
            with atomic_path(path) as tmp:
                tmp.write_bytes(data)
        return self

    def lines(self) -> list[str]:
        """What ``colour export`` prints: the transform, then each file."""
        lines = [self.transform.summary()]
        if self.clf is not None:
            lines.append(f"wrote {self.clf} (CLF, SMPTE ST 2136-1)")
        if self.amf is not None:
            lines.append(f"wrote {self.amf} (AMF 2.0, input transform {self.clf.name}, "
                         f"{'applied' if self.applied else 'not applied'})")
        if self.dctl is not None:
            lines.append(f"wrote {self.dctl} (DaVinci Resolve DCTL)")
        return lines


def build_aces(
    fit: ColourFit,
    camera: str,
    *,
    clf: str | os.PathLike | None = None,
    amf: str | os.PathLike | None = None,
    dctl: str | os.PathLike | None = None,
    space: str = "ACES2065-1",
    cat: str = "Bradford",
    max_delta_E: float = 0.2,
    lut_sizes: Sequence[int] = LUT_SIZES,
    applied: bool = False,
    created: str | None = None,
) -> ACESExport:
    """A characterisation's ACES input transform and the bytes of its CLF, AMF and/or DCTL (nothing written).

    Parameters
    ----------
    fit, camera
        The characterisation and the camera's name.
    clf, amf, dctl
        The files to write; ``amf`` names the ``clf`` (both needed). The
        model is baked only for a CLF (a DCTL holds the model's own terms).
    space, cat, max_delta_E, lut_sizes
        See :func:`camcal.colour.export.aces.input_transform`.
    applied
        The AMF's ``applied``: the images it goes with already hold the transform.
    created
        The AMF's ``xs:dateTime`` (default: now, UTC).

    Returns
    -------
    ACESExport
        Not yet written: :meth:`ACESExport.write` writes the files.

    Raises
    ------
    CamcalError
        An AMF without its CLF, two outputs on one path, an AMF or DCTL the
        transform has no form for (:func:`camcal.colour.export.amf.amf_text`,
        :func:`camcal.colour.export.dctl.dctl_text`).
    """
    from camcal import __version__

    if amf is not None and clf is None:
        raise CamcalError("--amf names the CLF it goes with: give --clf OUT.clf too")
    targets = [Path(path).resolve() for path in (clf, amf, dctl) if path is not None]
    if len(set(targets)) != len(targets):
        raise CamcalError("--clf, --amf and --dctl must name different files")
    transform = input_transform(fit, camera, space=space, cat=cat, max_delta_E=max_delta_E, lut_sizes=lut_sizes,
                                bake=clf is not None)
    texts: dict[Path, bytes] = {}
    if clf is not None:
        clf_data = clf_text(transform, f"camcal {__version__}").encode("utf-8")
        texts[Path(clf)] = clf_data
    if amf is not None:
        from camcal.colour.export.amf import amf_text

        relative = Path(os.path.relpath(Path(clf).absolute(), Path(amf).absolute().parent)).as_posix()
        texts[Path(amf)] = amf_text(transform, relative, hashlib.sha256(clf_data).digest(),
                                    created or utc_timestamp(), applied=applied).encode("utf-8")
    if dctl is not None:
        from camcal.colour.export.dctl import dctl_text

        texts[Path(dctl)] = dctl_text(transform).encode("utf-8")
    return ACESExport(transform, *(None if p is None else Path(p) for p in (clf, amf, dctl)), applied=applied,
                      contents=tuple(texts.items()))


def export_aces(fit: ColourFit, camera: str, **options) -> ACESExport:
    """:func:`build_aces`, then write the files (each atomically, after all are built)."""
    return build_aces(fit, camera, **options).write()
