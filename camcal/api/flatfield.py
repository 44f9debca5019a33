"""``camcal.fit_flat_field``: ``colour flatfield``, a lens's flat field and vignetting from grey cards or neutral
patches, written as camcal's JSON, a gain EXR and a Lensfun vignetting entry.

(:mod:`camcal.colour.flatfield` is the model and the fit; this module reads the inputs, checks the options as
the command does, and writes the files, all or none.)
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from camcal.base.errors import CamcalError

if TYPE_CHECKING:
    from camcal.colour.flatfield import FlatField, RadialTerms

__all__ = ["FlatFieldFit", "fit_flat_field"]


@dataclass(frozen=True)
class FlatFieldFit:
    """What :func:`fit_flat_field` fitted and wrote.

    Attributes
    ----------
    flat : FlatField
        The model (per-channel ``pa`` falloff about the optical centre, optional smooth term), its residual and
        the gain's uncertainty.
    images : tuple of Path
        The grey-card images read (empty for patches).
    lensfun : RadialTerms or None
        With ``lensfun``: the one ``pa`` term set written and the largest deviation it leaves.
    files : tuple of (Path, str)
        ``(path, kind)`` of the files written: ``flat field``, ``gain exr``, ``lensfun``.
    """

    flat: FlatField
    images: tuple[Path, ...] = ()
    lensfun: RadialTerms | None = None
    files: tuple[tuple[Path, str], ...] = ()

    def save(self, path: str | os.PathLike) -> Path:
        """Write the flat field (JSON, atomically); its path."""
        from camcal.io.flatfield import save_flat_field

        return save_flat_field(self.flat, path)

    def lines(self) -> list[str]:
        """What ``colour flatfield`` prints."""
        lines = [self.flat.summary()]
        if self.lensfun is not None:
            k = self.lensfun.k
            lines.append(f"Lensfun pa vignetting k1 {k[0]:.5g} k2 {k[1]:.5g} k3 {k[2]:.5g}: one falloff for every "
                         f"channel, within {100 * self.lensfun.max_deviation:.2f} % of the flat field over the frame")
        return lines

    def figures(self) -> dict[str, Any]:
        """The figures of ``colour flatfield --json``."""
        flat = self.flat
        figures: dict[str, Any] = {
            "source": flat.source, "n_images": len(self.images), "image_size": list(flat.image_size),
            "centre_px": [float(v) for v in flat.centre], "k": [[float(v) for v in row] for row in flat.k],
            "smooth_degree": flat.smooth_degree, "n_samples": flat.n_samples, "n_rejected": flat.n_rejected,
            "residual_rms": [float(v) for v in flat.residual_rms],
            "gain_sigma_max": [float(v) for v in flat.gain_sigma_max],
        }
        if self.lensfun is not None:
            figures["lensfun"] = {"k": [float(v) for v in self.lensfun.k],
                                  "max_deviation": float(self.lensfun.max_deviation)}
        return figures


def fit_flat_field(
    images: Sequence[str | os.PathLike] | str | os.PathLike | None = None,
    *,
    patches: str | os.PathLike | None = None,
    image_size: tuple[int, int] | None = None,
    mask: str | os.PathLike | None = None,
    linear: bool = False,
    smooth_degree: int = 0,
    fit_centre: bool = True,
    out: str | os.PathLike | None = None,
    gain_exr: str | os.PathLike | None = None,
    lensfun: str | os.PathLike | None = None,
    focal_mm: float | None = None,
    aperture: float | None = None,
    distance_m: float | None = None,
    lens_name: str = "camcal flat field",
    sensor_width_mm: float | None = None,
) -> FlatFieldFit:
    """Fit a lens's flat field and vignetting (``camcal colour flatfield``).

    Per channel, a radial falloff ``1 + k1 r^2 + k2 r^4 + k3 r^6`` (Lensfun's
    ``pa`` model, ``r`` 1 at the half diagonal) about a fitted optical
    centre, times an optional smooth non-radial term; 1 at the optical
    centre. Fitted robustly: what is not the card (background, dust, the
    card's edge) is rejected.

    Parameters
    ----------
    images : path, glob or sequence of them, optional
        Grey-card photos, one size, linear: raw files, EXR, 16-bit or float TIFF (an 8-bit image only with
        ``linear``). The card should fill most of the frame, 1 to 2 stops below clipping, evenly lit. Give this
        or ``patches``.
    patches : path, optional
        A CSV ``x,y,R,G,B,patch[,shot]``: the chart's neutral patches seen at several places in the frame
        (centre in pixels, linear value, patch name, photo); needs ``image_size``.
    image_size : (int, int), optional
        ``(W, H)`` of the photos the patches come from.
    mask : path, optional
        An image whose non-zero pixels are the card (default: found by the fit).
    linear : bool
        The 8-bit images hold linear values.
    smooth_degree : int
        Degree 0 to 4 of the non-radial term (0: radial only).
    fit_centre : bool
        Fit the optical centre (else the image centre).
    out : path, optional
        The flat field as JSON.
    gain_exr : path, optional
        The gain per pixel as a float RGB EXR (divide a linear image by it).
    lensfun : path, optional
        A Lensfun database file (``.xml``) with the ``pa`` vignetting entry; needs ``focal_mm``, ``aperture``
        and ``distance_m``. An existing file with one ``<lens>`` (``rig export --to lensfun``'s, or an earlier
        lens state's) gets the entry added, fitted about its centre.
    focal_mm, aperture, distance_m : float, optional
        The lens state of the grey cards (Lensfun's entry is for one).
    lens_name : str
        The Lensfun ``<lens>``'s model name.
    sensor_width_mm : float, optional
        The sensor width for Lensfun's crop factor (default 36 mm).

    Returns
    -------
    FlatFieldFit

    Raises
    ------
    CamcalError
        Bad input (images of different sizes, a card too dark, an 8-bit image without ``linear``, a bad option;
        one line naming it); nothing is written then.
    """
    from camcal.pipelines.flatfield import flat_field_from_image_files, flat_field_from_patch_file

    if (images is None) == (patches is None):
        raise CamcalError("give grey-card --images or --patches (one of them)")
    if patches is not None and image_size is None:
        raise CamcalError("--patches needs --image-size W H (the photos' size)")
    if patches is not None and (mask is not None or linear):
        raise CamcalError("--mask and --linear apply to --images only")
    if image_size is not None and (images is not None or min(image_size) < 2):
        raise CamcalError(f"--image-size goes with --patches and must be at least 2 2, got {image_size}")
    if not 0 <= smooth_degree <= 4:
        raise CamcalError(f"--smooth-degree must be 0 to 4, got {smooth_degree}")
    state = {"--focal-mm": focal_mm, "--aperture": aperture, "--distance-m": distance_m}
    if lensfun is not None:
        missing = [name for name, value in state.items() if value is None]
        if missing:
            raise CamcalError(f"--lensfun needs the lens state: {', '.join(missing)}")
    elif any(value is not None for value in state.values()) or sensor_width_mm is not None:
        raise CamcalError("--focal-mm, --aperture, --distance-m and --sensor-width-mm apply to --lensfun only")
    for path, suffix, option in ((out, ".json", "--out"), (gain_exr, ".exr", "--gain-exr"),
                                 (lensfun, ".xml", "--lensfun")):
        if path is not None and Path(path).suffix.lower() != suffix:
            raise CamcalError(f"{option} must end in {suffix}, got {Path(path).name!r}")
    if lensfun is not None:
        from camcal.io.flatfield import check_lensfun_file

        check_lensfun_file(lensfun)
    read: tuple[Path, ...] = ()
    if images is not None:
        flat, files = flat_field_from_image_files(images, mask=mask, linear=linear, smooth_degree=smooth_degree,
                                                  fit_centre=fit_centre)
        read = tuple(files)
    else:
        flat = flat_field_from_patch_file(patches, (int(image_size[0]), int(image_size[1])),
                                          smooth_degree=smooth_degree, fit_centre=fit_centre)
    terms, files = _write(flat, out, gain_exr, lensfun, focal_mm, aperture, distance_m, lens_name, sensor_width_mm)
    return FlatFieldFit(flat, read, terms, files)


def _write(flat, out, gain_exr, lensfun, focal_mm, aperture, distance_m, lens_name, sensor_width_mm):
    """Write the outputs asked for, all or none (those written are removed when a later one fails)."""
    from camcal.io.flatfield import save_flat_field, write_gain_exr, write_lensfun_vignetting

    written: list[tuple[Path, str]] = []
    terms = None
    try:
        if out is not None:
            written.append((save_flat_field(flat, out), "flat field"))
        if gain_exr is not None:
            written.append((write_gain_exr(flat, gain_exr), "gain exr"))
        if lensfun is not None:
            terms = write_lensfun_vignetting(flat, lensfun, focal_mm=focal_mm, aperture=aperture,
                                             distance_m=distance_m, model=lens_name, sensor_width_mm=sensor_width_mm)
            written.append((Path(lensfun), "lensfun"))
    except BaseException:
        for path, _ in written:
            path.unlink(missing_ok=True)
        raise
    return terms, tuple(written)
