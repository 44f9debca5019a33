"""Colour pipelines: chart photos, patch files and stereo pairs in, colour results out.

Each step takes paths (or arrays and another layer's results) and hands
arrays to the pure colour maths (:mod:`camcal.colour`):

- :func:`patches_from_chart`: read a chart photo, detect, sample and pair
  its patches with the reference chart (``colour fit --chart``);
- :func:`capture_from_chart`: a ColorChecker photo as a capture for
  sensitivity estimation (``colour sensitivities --chart``);
- :func:`match_images`: the stereo route of a camera match on a rectified
  pair: the correspondences (:mod:`camcal.geometry.correspondence`), then
  :func:`camcal.colour.match.routes.match_correspondences`;
- :func:`match_image_files`, :func:`match_patch_files`: ``colour match``'s
  image and chart routes from files.
"""

from __future__ import annotations

import dataclasses
import os
from typing import Any

import numpy as np

from camcal.base.errors import CamcalError
from camcal.colour.chart.detect import ChartPatches, patches_from_image
from camcal.colour.chart.linearise import Linearisation
from camcal.colour.chart.reference import ReferenceChart, reference_chart
from camcal.colour.fit.record import ColourFit
from camcal.colour.flatfield import FlatField, correct_flat_field
from camcal.colour.match.models import LUT_SMOOTHING
from camcal.colour.match.routes import MatchResult, encoding_linearisation, match_charts, match_correspondences
from camcal.colour.spectral.captures import Capture, chart_reflectances, check_chart_spectra
from camcal.colour.spectral.data import adapt_XYZ
from camcal.colour.spectral.sensitivities import DEFAULT_WAVELENGTHS
from camcal.geometry.correspondence import stereo_correspondences
from camcal.geometry.rectify import RectifyWarper, rectify_calibrated
from camcal.io.colourimage import read_image
from camcal.io.patches import read_patch_csv
from camcal.io.raw import is_raw, read_raw
from camcal.io.ssf import read_illuminant_spd

__all__ = ["chart_references", "patches_from_chart", "capture_from_chart", "match_images", "match_image_files", "match_patch_files"]


#: Suffixes of a chart's own reference file (CGATS.17) given as ``reference``.
CGATS_SUFFIXES = (".txt", ".it8", ".cgats", ".cie", ".cxf.txt")


def chart_references(reference: str | os.PathLike | None = None, chart_type: str = "auto",
                     illuminant: str = "D50") -> list[ReferenceChart]:
    """The reference charts a photo is searched for, in the order they are tried.

    Parameters
    ----------
    reference
        A reference name (:func:`camcal.colour.chart.reference.reference_chart`),
        a chart's CGATS.17 file (:mod:`camcal.io.cgats`: the IT8.7/2's, or any
        chart's own measurements, patches row by row), or ``None``: the chart
        type's own data (X-Rite's, from colour-science).
    chart_type
        ``auto`` or a layout of :data:`camcal.colour.chart.layouts.LAYOUTS`.
        ``auto`` with no ``reference`` tries the Digital SG, then the 24-patch
        ColorChecker (Classic, Passport, Mini and Nano look alike); a given
        reference names the chart's family itself (a CGATS file's by its
        number of patches: 288 IT8.7/2, 140 Digital SG, 24 ColorChecker).
    illuminant
        White the reference XYZ are adapted to.

    Raises
    ------
    CamcalError
        An unknown chart type, an IT8.7/2 without its CGATS file, a reference
        whose grid is not the chart type's.
    """
    from camcal.colour.chart.layouts import LAYOUT_FAMILIES, chart_layout
    from camcal.colour.chart.reference import reference_from_measurements
    from camcal.io.cgats import read_cgats

    layout = None if chart_type == "auto" else chart_layout(chart_type)
    if reference is not None and (os.fspath(reference).lower().endswith(CGATS_SUFFIXES) or os.path.isfile(reference)):
        data = read_cgats(reference)
        if layout is None:
            by_count = {chart_layout(name).n_patches: name for name in LAYOUT_FAMILIES}
            if len(data.names) not in by_count:
                raise CamcalError(f"{reference}: {len(data.names)} patches is no chart camcal knows (288 IT8.7/2, "
                                  "140 Digital SG, 24 ColorChecker); name it with --chart-type")
            layout = chart_layout(by_count[len(data.names)])
        return [reference_from_measurements(os.path.basename(os.fspath(reference)), data.names, data.XYZ,
                                            layout.name, illuminant=illuminant)]
    if layout is not None and layout.reference is None:
        raise CamcalError(f"the {layout.title} chart's reference values come with it: give its CGATS file with "
                          "--reference FILE")
    if reference is None:
        names = [layout.name] if layout is not None else [n for n in LAYOUT_FAMILIES if chart_layout(n).reference]
        return [dataclasses.replace(reference_chart(chart_layout(n).reference, illuminant), layout=n) for n in names]
    chart = reference_chart(os.fspath(reference), illuminant)
    if layout is None:
        return [chart]
    if (chart.rows, chart.columns) != (layout.rows, layout.columns) or len(chart.XYZ) != layout.n_patches:
        raise CamcalError(f"reference {chart.name!r} has {len(chart.XYZ)} patches in {chart.rows} x {chart.columns}, "
                          f"the {layout.title} {layout.n_patches} in {layout.rows} x {layout.columns}")
    return [dataclasses.replace(chart, layout=layout.name)]


def patches_from_chart(
    image_path: str | os.PathLike,
    reference: str | os.PathLike | None = None,
    *,
    corners: Any = None,
    keep_clipped: bool = False,
    illuminant: str = "D50",
    detector: str = "auto",
    flat_field: FlatField | None = None,
    chart_type: str = "auto",
) -> ChartPatches:
    """Detect, sample and pair a chart photo's patches with reference XYZ.

    Parameters
    ----------
    image_path
        The photo (8/16-bit or float, or a raw file; :func:`camcal.io.colourimage.read_image`).
    reference
        Reference chart name or CGATS file, ``None`` for the chart type's own
        (:func:`chart_references`).
    corners
        ``(4, 2)`` manual grid corners; ``None`` detects the chart
        (:func:`camcal.colour.chart.detect.detect_chart`, on a normalised,
        sRGB-encoded view of a raw file's linear image).
    keep_clipped
        Keep patches flagged clipped (dropped by default). A raw file's
        patches are clipped only where its pixels are saturated: dark ones
        are measured (values below black kept) and weighted by their
        signal-to-noise ratio.
    illuminant
        White of the reference XYZ (the chart's data are adapted to it when
        they were measured under another, see ``reference_chart``).
    detector
        ``auto``, ``segmentation`` or ``cv2.mcc`` (:func:`camcal.colour.chart.detect.detect_chart`).
    flat_field
        A lens's flat field the photo is divided by before sampling
        (:func:`camcal.colour.flatfield.correct_flat_field`; the photo must be linear).
    chart_type
        ``auto`` (detected) or a layout (:func:`chart_references`).

    Returns
    -------
    ChartPatches
        Code values normalised to [0, 1] and XYZ relative to the chart's
        white (:func:`camcal.colour.chart.detect.patches_from_image`).
    """
    charts = chart_references(reference, chart_type, illuminant)
    if corners is not None and len(charts) > 1:
        charts = charts[-1:]  # corners without a chart type: the 24-patch ColorChecker, as before
    if is_raw(image_path):
        raw = read_raw(image_path)
        RGB = raw.RGB if flat_field is None else correct_flat_field(raw.RGB, flat_field)
        return patches_from_image(RGB, charts, corners=corners, keep_clipped=keep_clipped,
                                  saturated=raw.saturated, linear=True, detector=detector)
    image = read_image(image_path)
    if flat_field is not None:
        image = correct_flat_field(image, flat_field)
    return patches_from_image(image, charts, corners=corners, keep_clipped=keep_clipped, detector=detector)


def capture_from_chart(
    image_path: str | os.PathLike,
    illuminant: str,
    wavelengths: Any = DEFAULT_WAVELENGTHS,
    *,
    reflectances: str = "BabelColor Average",
    corners: Any = None,
) -> Capture:
    """A ColorChecker 24 photo (linear: raw or linear TIFF/EXR) as a capture.

    The chart is found and sampled as by ``colour fit`` (clipped patches
    dropped); each patch's reflectance comes from colour-science's spectral
    data ``reflectances`` (``BabelColor Average``, ``ColorChecker N Ohta`` or
    ``ISO 17321-1``), matched by patch name
    (:func:`camcal.colour.spectral.captures.chart_reflectances`).
    ``illuminant``: a CIE name or a CSV file (:func:`camcal.io.ssf.read_illuminant_spd`).
    """
    check_chart_spectra(reflectances)
    wavelengths = np.asarray(wavelengths, dtype=np.float64)
    found = patches_from_chart(image_path, corners=corners, chart_type="classic")
    names = found.patches.names
    R = chart_reflectances(names, reflectances, wavelengths)
    return Capture(names, R, found.patches.RGB, read_illuminant_spd(illuminant, wavelengths), illuminant,
                   str(image_path))


def match_images(
    RGB_A: Any,
    RGB_B: Any,
    *,
    model: str = "matrix3x3",
    robust: str = "lmeds-irls",
    a_is_left: bool | None = None,
    fit_target: ColourFit | None = None,
    source: str | None = None,
    target: str | None = None,
    linearisation: Linearisation | None = None,
    test_fraction: float = 0.25,
    tile_px: int = 16,
    max_samples: int = 40000,
    smoothing: float = LUT_SMOOTHING,
    seed: int = 0,
    provenance_source: str | None = None,
    **stereo: Any,
) -> MatchResult:
    """Fit a camera B -> camera A colour match from a rectified stereo pair.

    The dense correspondences come from
    :func:`camcal.geometry.correspondence.stereo_correspondences` (SGBM both
    ways, left-right check); the fit from
    :func:`camcal.colour.match.routes.match_correspondences`.

    Parameters
    ----------
    RGB_A, RGB_B
        ``(H, W, 3)`` LINEAR RGB of the rectified views of A (target) and B
        (source).
    a_is_left
        Whether A is the left view (``None``: found from the data).
    model, robust, fit_target, source, target, linearisation, test_fraction, tile_px, max_samples, smoothing, seed, provenance_source
        See :func:`camcal.colour.match.routes.match_correspondences`.
    **stereo
        Options of :func:`stereo_correspondences`.

    Returns
    -------
    MatchResult
        With its ``correspondences``.
    """
    if not 0.0 < test_fraction < 1.0:
        raise CamcalError(f"test_fraction must be between 0 and 1, got {test_fraction}")
    corr = stereo_correspondences(RGB_A, RGB_B, a_is_left=a_is_left, **stereo)
    result = match_correspondences(
        corr.source, corr.target, corr.valid, counts=corr.counts, model=model, robust=robust,
        fit_target=fit_target, source=source, target=target, linearisation=linearisation,
        test_fraction=test_fraction, tile_px=tile_px, max_samples=max_samples, smoothing=smoothing, seed=seed,
        provenance_source=provenance_source,
    )
    return dataclasses.replace(result, correspondences=corr)


def match_image_files(
    images: dict[str, str | os.PathLike],
    *,
    rig: Any = None,
    rectified: bool = False,
    fits: dict[str, ColourFit] | None = None,
    encoding: str = "linear",
    model: str = "matrix3x3",
    robust: str = "lmeds-irls",
    seed: int = 0,
) -> MatchResult:
    """The image route from files: read, linearise, rectify if needed, match.

    Parameters
    ----------
    images
        Two entries ``{target_name: path, source_name: path}`` in that order:
        the first camera is the target (A), the second is matched to it (B).
    rig
        A :class:`camcal.model.rig.Rig` holding both cameras, or ``None``. With a
        rig, the left view is the camera further along the rectified x axis'
        negative side; unless ``rectified``, both images are rectified with
        :func:`camcal.geometry.rectify.rectify_calibrated` (undistortion and
        rectification in one remap) after linearisation.
    rectified
        The images are rectified already (required without a rig).
    fits
        Characterisations by camera name: a camera's fit gives its
        linearisation, the target's fit the XYZ for Delta E.
    encoding
        Encoding of cameras without a fit: ``linear`` or a transfer
        function name (``sRGB``, ``ITU-R BT.709``, ``ARRI LogC3``...).
    model, robust, seed
        See :func:`match_images`.

    Returns
    -------
    MatchResult
    """
    if len(images) != 2:
        raise CamcalError(f"colour match needs exactly two cameras' images, got {len(images)}: {', '.join(images)}")
    fits = fits or {}
    for name in fits:
        if name not in images:
            raise CamcalError(f"a fit is given for camera {name!r}, which has no image")
    target, source = list(images)
    if rig is None and not rectified:
        raise CamcalError("without a rig the images must already be rectified (say so with --rectified)")
    linear = {}
    linearisations = {}
    for name, path in images.items():
        lin = fits[name].linearisation if name in fits else encoding_linearisation(encoding)
        linearisations[name] = lin
        linear[name] = lin.apply(read_image(path))
    a_is_left = None
    if rig is not None:
        for name in images:
            rig.camera(name)
        result = rectify_calibrated(rig, [target, source])
        x = {name: float((result.R_rect @ rig.camera(name).c)[0]) for name in images}
        a_is_left = x[target] < x[source]
        if not rectified:
            warper = RectifyWarper(result.rig)
            linear = {name: warper.warp(name, image.astype(np.float32)).astype(np.float64)
                      for name, image in linear.items()}
    if linear[target].shape != linear[source].shape:
        raise CamcalError(f"the two images differ in size: {linear[target].shape[1]}x{linear[target].shape[0]} "
                          f"and {linear[source].shape[1]}x{linear[source].shape[0]} px")
    return match_images(linear[target], linear[source], model=model, robust=robust, a_is_left=a_is_left,
                        fit_target=fits.get(target), source=source, target=target,
                        linearisation=linearisations[source], seed=seed,
                        provenance_source=f"{images[target]}, {images[source]}")


def match_patch_files(
    fits: dict[str, ColourFit],
    patches: dict[str, str | os.PathLike],
    *,
    test_patches: dict[str, str | os.PathLike] | None = None,
    model: str = "matrix3x3",
    robust: str = "none",
) -> MatchResult:
    """The chart route from files: two fits and the two cameras' patch CSVs.

    Parameters
    ----------
    fits
        ``{target_name: fit, source_name: fit}``, target first.
    patches
        Patch CSVs of the same chart by camera name (code values in each
        fit's encoding; the target's XYZ column is the reference, adapted to
        the target fit's white as that fit was).
    test_patches
        Independent patch CSVs by camera name, optional.
    model, robust
        See :func:`match_charts`.

    Returns
    -------
    MatchResult
    """
    if len(fits) != 2 or set(patches) != set(fits):
        raise CamcalError("the chart route needs a fit and a patch file for each of two cameras, got fits for "
                          f"{', '.join(fits) or 'none'} and patches for {', '.join(patches) or 'none'}")
    target, source = list(fits)

    def pair(files: dict) -> tuple:
        if set(files) != set(fits):
            raise CamcalError(f"patch files must name the cameras {target} and {source}, got {', '.join(files)}")
        sets = {name: read_patch_csv(path) for name, path in files.items()}
        if sets[target].names != sets[source].names:
            raise CamcalError(f"the patch files of {target} and {source} list different patches "
                              f"({len(sets[target])} and {len(sets[source])})")
        return sets[source], sets[target]

    train_B, train_A = pair(patches)
    test = None
    if test_patches:
        test_B, test_A = pair(test_patches)
        test = (test_B.RGB, test_A.RGB)
    reference = train_A.XYZ
    fit_A = fits[target]
    if fit_A.adaptation is not None:
        reference = adapt_XYZ(reference, fit_A.training_white_XYZ, fit_A.target_white_XYZ, fit_A.adaptation)
    return match_charts(fits[source], fits[target], train_B.RGB, train_A.RGB, XYZ_reference=reference,
                        test=test, model=model, robust=robust, source=source, target=target,
                        provenance_source=f"{patches[target]}, {patches[source]}")
