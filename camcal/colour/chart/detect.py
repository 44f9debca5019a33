"""Chart detection in an image and patch sampling: an image array to patches beside reference XYZ.

Detection (:func:`detect_chart`), on a normalised, sRGB-encoded view of
the image (a raw file's linear RGB is too dark and green to detect on):
camcal's segmentation (:mod:`camcal.colour.chart.find`: square regions on
a lattice, oriented by the reference chart's colours; it also finds the
classic chart on a ColorChecker Passport page), and where it finds none,
OpenCV's ``cv2.mcc`` (contrib), its patch order checked against the
reference's colours. A homography from the chart's patch grid to
the image is fitted to the patch centres found. Any layout of
:mod:`camcal.colour.chart.layouts` (ColorChecker Classic, Passport, Mini,
Nano, Digital SG, IT8.7/2) is found by the segmentation, turned or seen in
a mirror (reported: :attr:`ChartDetection.mirrored`; the patches still come
in chart order); cv2.mcc finds the 24-patch charts only. A manual override takes the four
outer corners of the patch grid instead, in the order top-left (the corner
of ``dark skin``), top-right (``bluish green``), bottom-right
(``black``), bottom-left (``white``), pixel (0, 0) the centre of the
top-left pixel.

Sampling: the central ``fraction`` (default 0.5 of the cell width) of each
patch, mapped through the homography, a trimmed mean per channel (the
``trim`` fraction cut at each end), plus flags: ``clipped`` when more than
1 % of the patch's pixels touch the maximum code value in any channel
(or are flagged saturated by the raw reader), or touch 0 in an encoded
image, ``noisy`` when a channel's standard deviation exceeds 5 % of the
white's mean code value.

Linear raw data (black subtracted, ``clip_low=None``) have no floor: a
dark patch's pixels scatter around its true value, some below the black
level, and the mean of them all (negative values kept) is unbiased, where
clipping at black would bias it up and dropping it would lose the patch.
Each patch gets its signal-to-noise ratio ``snr`` (the norm of its mean
RGB over the norm of the standard errors of the mean, ``std / sqrt(n)``
of all its pixels) and a fit weight :func:`snr_weights`
``w = 1 / (1 + (SNR_REFERENCE / snr)^2)``: the patch's relative variance
``1 / snr^2`` beside :data:`REFERENCE_UNCERTAINTY` (1 %, the order of
the patch-to-patch and chart-to-chart variation of a ColorChecker's
reflectances, which bounds what any patch can teach), as inverse-variance
weights. A patch whose noise exceeds that uncertainty (``snr`` below
``SNR_REFERENCE`` = 100, weight below 0.5) is reported "too dark": it is
kept, measured and weighted, never dropped.

:func:`patches_from_image` chains them: detect (or take four corners),
sample, drop clipped (saturated) patches, pair the code values with the
reference chart's XYZ, weights set (an image file:
:func:`camcal.pipelines.colour.patches_from_chart`).
"""

from __future__ import annotations

from dataclasses import dataclass
from collections.abc import Sequence
from typing import TYPE_CHECKING, Any

import numpy as np

from camcal.base.errors import CamcalError
from camcal.base.extras import require
from camcal.colour.chart.patches import PatchSet
from camcal.colour.chart.reference import ReferenceChart

if TYPE_CHECKING:
    from camcal.colour.chart.layouts import ChartLayout

__all__ = [
    "ChartDetection",
    "detect_chart",
    "DETECTORS",
    "reference_linear_RGB",
    "chart_from_corners",
    "REFERENCE_UNCERTAINTY",
    "SNR_REFERENCE",
    "snr_weights",
    "PatchSamples",
    "sample_patches",
    "ChartPatches",
    "patches_from_image",
]


@dataclass(frozen=True, eq=False)
class ChartDetection:
    """Where the chart's patch grid is in the image.

    Attributes
    ----------
    H
        3x3 homography from grid coordinates (``u`` across the columns,
        ``v`` down the rows, both 0 to 1 over the whole patch grid) to
        pixels.
    corners
        ``(4, 2)`` pixel corners of the grid: top-left, top-right,
        bottom-right, bottom-left.
    rows, columns
        Patch grid.
    method
        ``"cv2.mcc"``, ``"segmentation"`` or ``"manual"``.
    fit_rms_px
        RMS distance between the detector's patch centres and the fitted
        grid (0 for manual corners).
    layout
        The chart's layout name (:data:`camcal.colour.chart.layouts.LAYOUTS`),
        ``""`` for a plain ``rows x columns`` grid.
    """

    H: np.ndarray
    corners: np.ndarray
    rows: int
    columns: int
    method: str
    fit_rms_px: float = 0.0
    layout: str = ""

    def _layout(self) -> ChartLayout:
        from camcal.colour.chart.layouts import ChartLayout, chart_layout

        if self.layout:
            return chart_layout(self.layout)
        return ChartLayout("grid", "grid", self.rows, self.columns, 1.0, None)

    def patch_centres(self) -> np.ndarray:
        """``(N, 2)`` pixel centres of every patch of the layout in chart order."""
        return _apply_H(self.H, self._layout().patch_uv())

    @property
    def mirrored(self) -> bool:
        """The chart is seen mirrored (in a mirror, or a flipped image): its grid's corners turn the other way.

        The signed area of the corners top-left, top-right, bottom-right,
        bottom-left is positive for a chart seen from its front (image ``y``
        down, grid ``v`` down).
        """
        x, y = self.corners[:, 0], self.corners[:, 1]
        return bool(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)) < 0)


def _grid_centres(rows: int, columns: int) -> np.ndarray:
    r, c = np.divmod(np.arange(rows * columns), columns)
    return np.column_stack([(c + 0.5) / columns, (r + 0.5) / rows])


def _apply_H(H: np.ndarray, uv: np.ndarray) -> np.ndarray:
    p = np.column_stack([uv, np.ones(len(uv))]) @ H.T
    return p[:, :2] / p[:, 2:3]


_UNIT_CORNERS = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])


def chart_from_corners(corners: Any, rows: int = 4, columns: int = 6, layout: str = "") -> ChartDetection:
    """A detection from four manual corners of the patch grid.

    Parameters
    ----------
    corners
        ``(4, 2)`` pixels: top-left (dark skin), top-right (bluish green),
        bottom-right (black), bottom-left (white).
    """
    import cv2

    corners = np.asarray(corners, dtype=np.float64)
    if corners.shape != (4, 2) or not np.all(np.isfinite(corners)):
        raise CamcalError(f"need 4 corners as (x, y) pixel pairs, got shape {corners.shape}")
    area = 0.5 * np.abs(np.dot(corners[:, 0], np.roll(corners[:, 1], 1)) - np.dot(corners[:, 1], np.roll(corners[:, 0], 1)))
    if area < 16.0:
        raise CamcalError("the 4 chart corners enclose no area")
    H = cv2.getPerspectiveTransform(_UNIT_CORNERS.astype(np.float32), corners.astype(np.float32))
    return ChartDetection(np.asarray(H, dtype=np.float64), corners, rows, columns, "manual", 0.0, layout)


def _mcc(view: np.ndarray, rows: int, columns: int) -> np.ndarray | None:
    """cv2.mcc's ``(24, 2)`` patch centres in chart order on an 8-bit RGB view, or ``None``."""
    import cv2

    bgr = np.ascontiguousarray(view[:, :, ::-1])
    detector = cv2.mcc.CCheckerDetector_create()
    if hasattr(detector, "setColorChartType"):
        # OpenCV 5: the chart type is a detector setting (unset, it is not MCC24)
        # and process() takes only (image, nc).
        detector.setColorChartType(cv2.mcc.MCC24)
        found = detector.process(bgr, 1)
    else:  # OpenCV 4.x: process(image, chartType, nc)
        found = detector.process(bgr, cv2.mcc.MCC24, 1)
    if not found:
        return None
    quads = np.asarray(detector.getBestColorChecker().getColorCharts(), dtype=np.float64).reshape(-1, 4, 2)
    if quads.shape[0] != rows * columns:
        return None
    return quads.mean(axis=1)


def _grid_fit(centres: np.ndarray, index: np.ndarray, rows: int, columns: int, method: str,
              layout: str = "") -> ChartDetection:
    """The chart grid's homography by least squares on the patch centres found (``index``: chart order).

    A centre more than 3 times the median distance (and over 1 px) from
    the first fit is left out and the grid fitted again (a patch seen
    merged with its neighbour's edge).
    """
    import cv2

    grid = _grid_centres(rows, columns)[index]
    keep = np.ones(len(grid), dtype=bool)
    for _ in range(2):
        H, _ = cv2.findHomography(grid[keep].astype(np.float64), centres[keep].astype(np.float64), 0)
        if H is None:
            raise CamcalError(f"the patch centres {method} found do not form a chart grid")
        distance = np.linalg.norm(_apply_H(H, grid) - centres, axis=1)
        outlier = distance > max(1.0, 3.0 * float(np.median(distance)))
        if not outlier.any() or (~outlier).sum() < 8:
            break
        keep = ~outlier
    rms = float(np.sqrt(np.mean(distance[keep] ** 2)))
    return ChartDetection(H, _apply_H(H, _UNIT_CORNERS), rows, columns, method, rms, layout)


def _oriented(view: np.ndarray, centres: np.ndarray, reference_RGB: Any, rows: int, columns: int):
    """cv2.mcc's centres in the order (as given or turned a half turn) whose colours agree best with the
    reference's, and that agreement (:func:`camcal.colour.chart.find.colour_score`)."""
    from camcal.colour.chart.find import colour_score, sample_view

    measured = sample_view(view, centres)
    half_turn = np.arange(rows * columns)[::-1]
    scores = [colour_score(measured, reference_RGB), colour_score(measured[half_turn], reference_RGB)]
    if scores[1] > scores[0]:
        return centres[half_turn], scores[1]
    return centres, scores[0]


DETECTORS = ("auto", "cv2.mcc", "segmentation")


def detect_chart(
    image: np.ndarray,
    rows: int = 4,
    columns: int = 6,
    *,
    linear: bool = False,
    reference_RGB: Any = None,
    detector: str = "auto",
    layout: str = "",
    cache: dict | None = None,
) -> ChartDetection:
    """Find a chart: camcal's segmentation, then OpenCV's ``cv2.mcc`` (24-patch charts).

    Both run on :func:`camcal.colour.chart.find.detection_view` (a linear
    image normalised per channel and sRGB-encoded), never on the linear
    values themselves. ``auto`` takes the segmentation's answer
    (:func:`camcal.colour.chart.find.find_chart_segmentation`, which needs
    ``reference_RGB`` to orient the chart, turned or mirrored) when it finds
    the chart, else cv2.mcc's (24-patch charts only): on synthesised raw captures
    (bench/bench_chart_detect.py) the segmentation found more charts, more
    accurately. With ``reference_RGB``, cv2.mcc's patch order is checked
    against the reference's colours too: it can return the chart a half turn
    round (seen on dim raw views), and its answer is refused when the colours
    do not agree (:data:`camcal.colour.chart.find.MIN_COLOUR_SCORE`).

    Parameters
    ----------
    image
        ``(H, W, 3)`` RGB: normalised code values, or linear with black 0
        when ``linear`` (raw).
    rows, columns
        The main patch grid (overridden by ``layout``).
    reference_RGB
        ``(rows * columns, 3)`` the main grid's linear RGB (for the segmentation's orientation).
    detector
        ``auto``, ``cv2.mcc`` or ``segmentation``.
    layout
        A layout of :data:`camcal.colour.chart.layouts.LAYOUTS` (its grid and
        where its other patches sit), or ``""`` for a plain grid.
    cache
        A dict kept between calls on the same image (one image searched for
        several layouts): the segmentation is made once.

    Returns
    -------
    ChartDetection

    Raises
    ------
    CamcalError
        When no chart is found ("no ColorChecker found in the image").
    """
    from camcal.colour.chart.find import MIN_COLOUR_SCORE, detection_view, find_chart_segmentation
    from camcal.colour.chart.layouts import chart_layout

    if layout:
        rows, columns = chart_layout(layout).rows, chart_layout(layout).columns
    if detector not in DETECTORS:
        raise CamcalError(f"unknown chart detector {detector!r}, expected one of: {', '.join(DETECTORS)}")
    if detector == "cv2.mcc" and (rows, columns) != (4, 6):
        raise CamcalError("the cv2.mcc detector finds 24-patch ColorCheckers only; use the segmentation detector "
                          "or give --corners")
    if reference_RGB is not None:
        reference_RGB = np.asarray(reference_RGB, dtype=np.float64)[: rows * columns]
    if cache is not None and "view" in cache:
        view = cache["view"]
    else:
        view = detection_view(image, linear=linear)
        if cache is not None:
            cache["view"] = view
    tried = []
    if detector in ("auto", "segmentation") and reference_RGB is not None:
        tried.append("segmentation")
        found = find_chart_segmentation(view, reference_RGB, rows, columns,
                                        cache=None if cache is None else cache.setdefault("segments", {}))
        if found is not None:
            return _grid_fit(found.centres, found.index, rows, columns, "segmentation", layout)
    if detector in ("auto", "cv2.mcc") and (rows, columns) == (4, 6):
        tried.append("cv2.mcc")
        centres = _mcc(view, rows, columns)
        if centres is not None and reference_RGB is not None:
            centres, score = _oriented(view, centres, reference_RGB, rows, columns)
            if score < MIN_COLOUR_SCORE:
                centres = None
        if centres is not None:
            return _grid_fit(centres, np.arange(rows * columns), rows, columns, "cv2.mcc", layout)
    what = chart_layout(layout).title if layout and (rows, columns) != (4, 6) else "ColorChecker"
    raise CamcalError(
        f"no {what} found in the image ({' nor '.join(tried) or 'no detector ran'}); give its corners with --corners"
    )


REFERENCE_UNCERTAINTY = 0.01
SNR_REFERENCE = 1.0 / REFERENCE_UNCERTAINTY


def snr_weights(snr: Any) -> np.ndarray:
    """Inverse-variance fit weights from patch signal-to-noise ratios (see the module docstring).

    Examples
    --------
    >>> snr_weights([np.inf, 100.0, 10.0]).round(4).tolist()
    [1.0, 0.5, 0.0099]
    """
    snr = np.asarray(snr, dtype=np.float64)
    with np.errstate(divide="ignore"):
        ratio = np.where(snr > 0, SNR_REFERENCE / np.maximum(snr, 1e-300), np.inf)
    return np.maximum(1.0 / (1.0 + ratio**2), 1e-12)


def reference_linear_RGB(chart: ReferenceChart) -> np.ndarray:
    """The chart's linear sRGB (its XYZ through the sRGB matrix; for orienting a detection)."""
    colour = require("colour")

    return np.asarray(colour.XYZ_to_RGB(chart.XYZ, "sRGB", colour.XYZ_to_xy(chart.white_XYZ)), dtype=np.float64)


@dataclass(frozen=True, eq=False)
class PatchSamples:
    """Per-patch statistics of an image's patches (normalised code values).

    Attributes
    ----------
    RGB
        ``(N, 3)`` trimmed means.
    std
        ``(N, 3)`` standard deviations of the kept pixels.
    n_pixels
        ``(N,)`` pixels sampled per patch.
    clipped, noisy
        ``(N,)`` flags (see the module docstring).
    snr
        ``(N,)`` signal-to-noise ratio of each patch mean (``inf`` without noise).
    """

    RGB: np.ndarray
    std: np.ndarray
    n_pixels: np.ndarray
    clipped: np.ndarray
    noisy: np.ndarray
    snr: np.ndarray

    @property
    def weights(self) -> np.ndarray:
        """``(N,)`` fit weights (:func:`snr_weights`)."""
        return snr_weights(self.snr)

    @property
    def too_dark(self) -> np.ndarray:
        """``(N,)`` patches whose noise exceeds :data:`REFERENCE_UNCERTAINTY` (kept, weighted down)."""
        return self.snr < SNR_REFERENCE


def sample_patches(
    image: np.ndarray,
    detection: ChartDetection,
    *,
    fraction: float = 0.5,
    trim: float = 0.1,
    clip_low: float | None = 0.5 / 255,
    clip_high: float = 254.5 / 255,
    saturated: np.ndarray | None = None,
) -> PatchSamples:
    """Trimmed-mean code values of the central part of every patch.

    Parameters
    ----------
    image
        ``(H, W, 3)`` normalised code values.
    detection
        The chart's grid in the image.
    fraction
        Side of the sampled square as a fraction of the patch cell.
    trim
        Fraction cut at each end of every channel before averaging.
    clip_low, clip_high
        Code values counted as clipped (at or beyond); ``clip_low=None``
        for linear data with the black level subtracted (no floor: values
        below black are noise and stay in the mean).
    saturated
        ``(H, W)`` pixels flagged saturated (a raw file's), counted as clipped.

    Returns
    -------
    PatchSamples
    """
    import cv2

    if not 0 < fraction <= 1 or not 0 <= trim < 0.5:
        raise CamcalError(f"need 0 < fraction <= 1 and 0 <= trim < 0.5, got {fraction}, {trim}")
    height, width = image.shape[:2]
    layout = detection._layout()
    grid = layout.patch_uv()
    N = len(grid)
    RGB = np.zeros((N, 3))
    std = np.zeros((N, 3))
    n_pixels = np.zeros(N, dtype=int)
    clipped = np.zeros(N, dtype=bool)
    snr = np.full(N, np.inf)
    # the sampled square: ``fraction`` of the cell (a patch and its share of the gap)
    half = layout.patch_half_size() / layout.patch_fraction * fraction
    square = np.array([[-1, -1], [1, -1], [1, 1], [-1, 1]], dtype=np.float64)
    for i in range(N):
        quad = _apply_H(detection.H, grid[i] + square * half[i])
        x0, y0 = np.floor(quad.min(axis=0)).astype(int)
        x1, y1 = np.ceil(quad.max(axis=0)).astype(int) + 1
        if x0 < 0 or y0 < 0 or x1 > width or y1 > height:
            raise CamcalError(f"patch {i + 1} of the chart lies outside the image")
        mask = np.zeros((y1 - y0, x1 - x0), dtype=np.uint8)
        cv2.fillConvexPoly(mask, np.round(quad - [x0, y0]).astype(np.int32), 1)
        pixels = image[y0:y1, x0:x1][mask.astype(bool)]
        if pixels.shape[0] < 4:
            raise CamcalError(f"patch {i + 1} covers fewer than 4 pixels: the chart is too small")
        n_pixels[i] = pixels.shape[0]
        touching = np.any(pixels >= clip_high, axis=1)
        if clip_low is not None:
            touching |= np.any(pixels <= clip_low, axis=1)
        if saturated is not None:
            touching |= saturated[y0:y1, x0:x1][mask.astype(bool)]
        clipped[i] = np.mean(touching) > 0.01
        noise = float(np.linalg.norm(pixels.std(axis=0) / np.sqrt(pixels.shape[0])))
        ordered = np.sort(pixels, axis=0)
        k = int(np.floor(trim * ordered.shape[0]))
        kept = ordered[k : ordered.shape[0] - k]
        RGB[i] = kept.mean(axis=0)
        std[i] = kept.std(axis=0)
        if noise > 0:
            snr[i] = float(np.linalg.norm(RGB[i])) / noise
    white_level = max(float(np.max(RGB)), 1e-6)
    noisy = np.any(std > 0.05 * white_level, axis=1)
    return PatchSamples(RGB, std, n_pixels, clipped, noisy, snr)


@dataclass(frozen=True, eq=False)
class ChartPatches:
    """What a chart photo gave: patches (code values) and how they were found."""

    patches: PatchSet
    reference: ReferenceChart
    detection: ChartDetection
    samples: PatchSamples
    excluded: tuple[str, ...]

    @property
    def too_dark(self) -> tuple[str, ...]:
        """Names of the used patches whose noise exceeds the reference uncertainty (kept, weighted down)."""
        return tuple(n for n, dark, clip in zip(self.reference.patch_names, self.samples.too_dark,
                                                self.samples.clipped) if dark and n in self.patches.names)


def patches_from_image(
    image: np.ndarray,
    chart: ReferenceChart | Sequence[ReferenceChart],
    *,
    corners: Any = None,
    keep_clipped: bool = False,
    saturated: np.ndarray | None = None,
    linear: bool = False,
    detector: str = "auto",
) -> ChartPatches:
    """Detect, sample and pair a chart image's patches with reference XYZ.

    Parameters
    ----------
    image
        ``(H, W, 3)`` float RGB code values normalised to [0, 1] (as
        :func:`camcal.io.colourimage.read_image` gives).
    chart
        The reference chart (:func:`camcal.colour.chart.reference.reference_chart`),
        its XYZ under the white the patches are for, its layout
        (:attr:`ReferenceChart.layout`) what is looked for; or several, tried
        in turn (the chart type detected: the first found is used, so give the
        larger layouts first, :data:`camcal.colour.chart.layouts.LAYOUT_FAMILIES`).
    corners
        ``(4, 2)`` manual grid corners; ``None`` detects (:func:`detect_chart`).
    keep_clipped
        Keep patches flagged clipped (dropped by default).
    saturated
        ``(H, W)`` saturated pixels (a raw file's flags).
    linear
        The image is linear with the black level subtracted (raw): no floor
        at 0, values below black kept in the patch means, and the patches
        weighted by their signal-to-noise ratio (encoded images: no weights,
        their code values' noise is not the noise in linear light).
    detector
        :func:`detect_chart`'s ``detector``.

    Returns
    -------
    ChartPatches
        Code values normalised to [0, 1] and XYZ relative to the chart's
        white.
    """
    charts = [chart] if isinstance(chart, ReferenceChart) else list(chart)
    if corners is not None:
        chart = charts[0]
        detection = chart_from_corners(corners, chart.rows, chart.columns, chart.layout)
    else:
        misses, cache = [], {}
        for candidate in charts:
            if detector == "cv2.mcc" and len(charts) > 1 and (candidate.rows, candidate.columns) != (4, 6):
                continue
            try:
                detection = detect_chart(image, candidate.rows, candidate.columns, linear=linear,
                                         reference_RGB=reference_linear_RGB(candidate), detector=detector,
                                         layout=candidate.layout, cache=cache)
            except CamcalError as error:
                misses.append(str(error).split(";")[0])
                continue
            chart = candidate
            break
        else:
            raise CamcalError(f"{'; '.join(misses)}; give the chart type and its corners with --corners")
    if linear:
        samples = sample_patches(image, detection, clip_low=None, saturated=saturated)
    else:
        samples = sample_patches(image, detection, saturated=saturated)
    keep = np.ones(len(chart.patch_names), dtype=bool) if keep_clipped else ~samples.clipped
    excluded = tuple(n for n, k in zip(chart.patch_names, keep) if not k)
    # weights only where the noise is measured in linear light: a code value's noise is not the linear one
    patches = PatchSet(chart.patch_names, samples.RGB, chart.XYZ, samples.weights if linear else None).subset(keep)
    return ChartPatches(patches, chart, detection, samples, excluded)
