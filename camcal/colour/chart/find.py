"""Finding a colour chart on raw data: a normalised, encoded view and a segmentation detector.

A raw image is linear camera RGB, often dim (a chart 3 or more stops under,
the white patch at a few per cent of full scale) and green-heavy. Neither
detector sees it well as it is, so :func:`detection_view` makes a view for
detection only (sampling still reads the linear image): each channel
divided by its 99th percentile (a rough white balance and exposure in one
step, robust to a few highlights), negatives set to 0, the sRGB encoding
(IEC 61966-2-1) applied, 8 bits.

:func:`find_chart_segmentation` finds the chart on that view without
OpenCV's ``cv2.mcc``:

1. candidate patches: connected regions of adaptive thresholds of the grey
   view (several block sizes, after contrast equalisation, CLAHE) whose
   minimum-area rectangle they fill to 75 % or more, with an aspect ratio
   within 2:1; where those form no chart, the regions between colour edges
   instead (:func:`_flat_regions`: patches that touch, as on an IT8.7/2), kept
   when they fill 80 % of their convex hull (a patch in steep perspective
   is a parallelogram), the most common size kept where regions overlap;
2. neighbours: patches of similar area (ratio within 2) whose centres are
   closer than 1.9 patch sides; each connected group of eight or more (and
   a quarter of the chart's patches) is a candidate chart;
3. a lattice: the two step directions are the medians of the two clusters
   of neighbour steps (right-handed in the image); a breadth-first walk
   gives each patch integer lattice coordinates; a homography from the
   lattice to the centres (RANSAC, then least squares on the inliers)
   keeps the patches that fit;
4. the chart in the lattice: every placement of a ``rows x columns`` window
   (either way round), each of its four rotations and their four mirror
   images (a chart seen in a mirror, or a flipped image) is scored first by
   the number of patches it holds, then by how well the sampled colours
   agree with the reference chart's: the correlations of log luminance and
   of the log chromaticity ratios ``R/G`` and ``B/G`` over the patches (a
   camera's RGB is not sRGB, but these orderings survive any white balance
   and any monotone response). This also finds the classic chart on a
   ColorChecker Passport page (held either way round), beside the other
   page's patches of another size;
5. the grid: a homography from the chart's patch centres to the image by
   least squares over the patches found (a mirrored chart's turns the other
   way: :attr:`camcal.colour.chart.detect.ChartDetection.mirrored`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["detection_view", "colour_score", "sample_view", "MIN_COLOUR_SCORE", "MIN_PATCH_SHARE",
           "SegmentationResult", "find_chart_segmentation"]

_MAX_SIDE = 1600
#: The least colour agreement (:func:`colour_score`, at most 3) a chart's orientation must reach:
#: half the largest, so each of the three correlations is positive on average.
MIN_COLOUR_SCORE = 1.5


def detection_view(image: np.ndarray, *, linear: bool) -> np.ndarray:
    """An 8-bit sRGB-encoded view of an image for chart detection (see the module docstring).

    Parameters
    ----------
    image
        ``(H, W, 3)`` float RGB: linear (black 0, white 1; values below 0
        allowed) when ``linear``, else normalised code values in [0, 1].

    Examples
    --------
    >>> dim = np.dstack([np.linspace(-0.001, 0.02, 100).reshape(10, 10)] * 3)
    >>> view = detection_view(dim, linear=True)
    >>> int(view.min()), int(view.max())
    (0, 255)
    """
    image = np.asarray(image, dtype=np.float64)
    if linear:
        scale = np.percentile(image.reshape(-1, 3), 99.0, axis=0)
        scale = np.where(scale > 0, scale, max(float(image.max()), 1e-12))
        x = np.clip(image / scale, 0.0, 1.0)
        image = np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055)
    return np.ascontiguousarray((np.clip(image, 0, 1) * 255 + 0.5).astype(np.uint8))


@dataclass(frozen=True)
class SegmentationResult:
    """A chart found by segmentation: centres of the patches found, in chart order, at full size.

    Attributes
    ----------
    centres
        ``(N, 2)`` pixel centres of the patches found.
    index
        ``(N,)`` chart index of each (row-major, 0 = dark skin).
    n_candidates
        Patch-like regions seen in the image.
    score
        Colour agreement of the chosen orientation (sum of three
        correlations, at most 3).
    """

    centres: np.ndarray
    index: np.ndarray
    n_candidates: int
    score: float


def _candidates(small: np.ndarray, flat: bool = False) -> np.ndarray:
    """Patch-like regions: ``(K, 4)`` centre x, y, side, angle (degrees) of their rectangles.

    ``flat``: the regions between colour edges (:func:`_flat_regions`) instead of the thresholded ones.
    """
    import cv2

    grey = cv2.cvtColor(small, cv2.COLOR_RGB2GRAY)
    height, width = grey.shape
    long_side = max(height, width)
    clahe = cv2.createCLAHE(clipLimit=2.0, tileGridSize=(8, 8)).apply(grey)
    found = []
    min_area = max(36.0, (long_side / 160.0) ** 2)
    max_area = height * width / 30.0

    def add(mask: np.ndarray, least: float = min_area, convex: bool = False) -> None:
        contours, _ = cv2.findContours(mask, cv2.RETR_LIST, cv2.CHAIN_APPROX_SIMPLE)
        for contour in contours:
            area = cv2.contourArea(contour)
            if not least <= area <= max_area:
                continue
            (cx, cy), (w, h), angle = cv2.minAreaRect(contour)
            if w <= 0 or h <= 0 or max(w, h) > 2 * min(w, h):
                continue
            if convex:  # a patch in steep perspective is a parallelogram: convex, not filling its rectangle
                if area < 0.8 * cv2.contourArea(cv2.convexHull(contour)):
                    continue
                # the side of the cell: the region, the pixel its contour runs through and the 2 px edge
                found.append((cx, cy, np.sqrt(area) + 3.0, angle))
            elif area >= 0.75 * w * h:
                found.append((cx, cy, np.sqrt(w * h), angle))

    if flat:
        # regions bounded by thin edges: smaller than a thresholded patch of the same pitch
        add(_flat_regions(small), max(16.0, (long_side / 300.0) ** 2), convex=True)
    else:
        for source in (grey, clahe):
            for divisor in (12, 24, 48):
                block = max(3, int(long_side / divisor) | 1)
                for polarity, c in ((cv2.THRESH_BINARY, -2), (cv2.THRESH_BINARY_INV, 2)):
                    mask = cv2.adaptiveThreshold(source, 255, cv2.ADAPTIVE_THRESH_MEAN_C, polarity, block, c)
                    add(cv2.morphologyEx(mask, cv2.MORPH_OPEN, np.ones((3, 3), np.uint8)))
    if not found:
        return np.zeros((0, 4))
    found = np.array(found)
    # one candidate per region: the passes see the same patch many times, and keep the largest; between
    # edges, a region of two or three merged patches overlaps its patches: keep the most common size
    order = np.argsort(np.abs(np.log(found[:, 2] / np.median(found[:, 2])))) if flat else np.argsort(-found[:, 2])
    kept: list[int] = []
    for i in order:
        if not kept or np.all(np.hypot(*(found[kept, :2] - found[i, :2]).T) > 0.5 * found[kept, 2]):
            kept.append(int(i))
    return found[kept]


def _flat_regions(small: np.ndarray) -> np.ndarray:
    """A mask of the regions between colour edges: patches that touch their neighbours (IT8.7/2, no gaps).

    Edges: Canny's (hysteresis thresholds ``t / 2`` and ``t``, L2 gradient)
    on CIELAB's three channels (OpenCV's 8-bit ``L``, ``a``, ``b``; ``a``
    and ``b`` stretched so that their 1st to 99th percentiles span 0-255:
    a dim or desaturated capture's colour differences become edges) after a
    Gaussian blur (sigma 0.7 px), ``t`` per channel four times its median
    gradient (the noise of flat areas) and at least 6 code values; thickened
    to 2 px so that no region leaks into its diagonal neighbour.
    """
    import cv2

    Lab = cv2.cvtColor(cv2.GaussianBlur(small, (0, 0), 0.7), cv2.COLOR_RGB2Lab).astype(np.float32)
    for k in (1, 2):
        lo, hi = np.percentile(Lab[:, :, k], [1, 99])
        Lab[:, :, k] = (Lab[:, :, k] - lo) * (255.0 / max(hi - lo, 1.0))
    channels = np.clip(Lab, 0, 255).astype(np.uint8)
    edges = np.zeros(small.shape[:2], np.uint8)
    for k in range(3):
        channel = np.ascontiguousarray(channels[:, :, k])
        gradient = np.hypot(cv2.Sobel(channel, cv2.CV_32F, 1, 0), cv2.Sobel(channel, cv2.CV_32F, 0, 1))
        high = max(6.0, 4.0 * float(np.median(gradient)))
        edges |= cv2.Canny(channel, high / 2, high, L2gradient=True)
    edges = cv2.dilate(edges, np.ones((2, 2), np.uint8))
    return np.where(edges > 0, 0, 255).astype(np.uint8)


def _groups(cand: np.ndarray) -> tuple[list[np.ndarray], np.ndarray]:
    """Connected groups of neighbouring patches of similar size, largest first."""
    n = len(cand)
    d = np.hypot(*(cand[:, None, :2] - cand[None, :, :2]).transpose(2, 0, 1))
    side = cand[:, 2]
    ratio = side[:, None] / side[None, :]
    near = (d < 1.9 * np.minimum(side[:, None], side[None, :])) & (ratio > 0.7) & (ratio < 1.43)
    np.fill_diagonal(near, False)
    label = -np.ones(n, dtype=int)
    groups = []
    for s in range(n):
        if label[s] >= 0:
            continue
        stack, members = [s], []
        label[s] = len(groups)
        while stack:
            i = stack.pop()
            members.append(i)
            for j in np.flatnonzero(near[i] & (label < 0)):
                label[j] = len(groups)
                stack.append(j)
        groups.append(np.array(members))
    groups = [g for g in groups if len(g) >= 8]
    return sorted(groups, key=len, reverse=True), near


def _lattice(cand: np.ndarray, members: np.ndarray, near: np.ndarray):
    """Integer lattice coordinates of a group's patches and a homography lattice -> pixels."""
    import cv2

    xy = cand[:, :2]
    member_set = set(int(m) for m in members)
    steps = [xy[j] - xy[i] for i in members for j in np.flatnonzero(near[i]) if int(j) in member_set]
    if len(steps) < 8:
        return None
    steps = np.array(steps)
    steps[steps[:, 0] < 0] *= -1  # a step and its reverse are one direction
    angle = np.degrees(np.arctan2(steps[:, 1], steps[:, 0]))
    length = np.hypot(steps[:, 0], steps[:, 1])
    pitch = np.median(length)
    axial = length < 1.25 * pitch  # diagonal steps are longer: leave them out
    hist, edges = np.histogram(angle[axial], bins=36, range=(-90, 90))
    first = 0.5 * (edges[np.argmax(hist)] + edges[np.argmax(hist) + 1])
    diff = (angle - first + 90) % 180 - 90
    g1 = axial & (np.abs(diff) < 25)
    g2 = axial & (np.abs(diff) > 65)
    if g1.sum() < 3 or g2.sum() < 3:
        return None
    a = np.median(steps[g1], axis=0)
    s2 = steps[g2].copy()
    s2[s2[:, 1] < 0] *= -1
    b = np.median(s2, axis=0)
    if a[0] * b[1] - a[1] * b[0] < 0:
        a, b = b, a
    if a[0] * b[1] - a[1] * b[0] < 0:  # still left-handed: flip one axis
        b = -b
    basis_inv = np.linalg.inv(np.column_stack([a, b]))
    # the walk from the best connected patches (one may be two patches merged, off the lattice): the largest
    coords: dict = {}
    for seed in members[np.argsort(-near[members][:, members].sum(axis=1), kind="stable")[:3]]:
        walk = _walk(int(seed), xy, near, member_set, basis_inv)
        if len(walk) > len(coords):
            coords = walk
        if len(coords) > 0.5 * len(members):
            break
    if len(coords) < 8:
        return None
    ids = np.array(list(coords))
    lattice = np.array([coords[i] for i in ids], dtype=np.float64)
    H, inliers = cv2.findHomography(lattice, xy[ids], cv2.RANSAC, 0.2 * pitch)
    if H is None:
        return None
    keep = inliers.ravel().astype(bool)
    if keep.sum() < 8:
        return None
    H, _ = cv2.findHomography(lattice[keep], xy[ids][keep], 0)
    if H is None:
        return None
    return ids[keep], lattice[keep].astype(int), H, pitch


def _walk(seed: int, xy: np.ndarray, near: np.ndarray, member_set: set, basis_inv: np.ndarray) -> dict:
    """Integer lattice coordinates by a breadth-first walk over neighbours from ``seed``."""
    coords = {seed: (0, 0)}
    queue = [seed]
    while queue:
        i = queue.pop(0)
        for j in np.flatnonzero(near[i]):
            j = int(j)
            if j not in member_set or j in coords:
                continue
            pq = basis_inv @ (xy[j] - xy[i])
            r = np.round(pq)
            if np.abs(pq - r).max() > 0.3 or np.abs(r).sum() == 0:
                continue
            coords[j] = (coords[i][0] + int(r[0]), coords[i][1] + int(r[1]))
            queue.append(j)
    return coords


def _project(H: np.ndarray, uv: np.ndarray) -> np.ndarray:
    p = np.column_stack([uv, np.ones(len(uv))]) @ H.T
    return p[:, :2] / p[:, 2:3]


def _corr(x: np.ndarray, y: np.ndarray) -> float:
    x, y = x - x.mean(), y - y.mean()
    den = np.sqrt((x * x).sum() * (y * y).sum())
    return float((x * y).sum() / den) if den > 0 else 0.0


def sample_view(view: np.ndarray, centres: np.ndarray, radius: int | None = None) -> np.ndarray:
    """``(N, 3)`` mean linear RGB (the view decoded with a 2.2 power) in squares around ``centres``.

    ``radius`` defaults to a fifth of the median distance between neighbouring centres.
    """
    centres = np.asarray(centres, dtype=np.float64)
    if radius is None:
        d = np.linalg.norm(centres[:, None] - centres[None], axis=2)
        np.fill_diagonal(d, np.inf)
        radius = max(1, int(0.2 * np.median(d.min(axis=1))))
    height, width = view.shape[:2]
    out = np.zeros((len(centres), 3))
    for k, (x, y) in enumerate(np.round(centres).astype(int)):
        x0, x1 = max(0, x - radius), min(width, x + radius + 1)
        y0, y1 = max(0, y - radius), min(height, y + radius + 1)
        if x1 > x0 and y1 > y0:
            out[k] = np.power(view[y0:y1, x0:x1].reshape(-1, 3) / 255.0, 2.2).mean(axis=0)
    return out


def colour_score(measured: np.ndarray, reference: np.ndarray) -> float:
    """Agreement of the patches' colours with the reference's (see the module docstring, step 4).

    Examples
    --------
    >>> ref = np.array([[0.2, 0.1, 0.05], [0.1, 0.3, 0.1], [0.05, 0.1, 0.4], [0.9, 0.9, 0.9], [0.03, 0.03, 0.03]])
    >>> round(colour_score(ref * [0.5, 1.0, 0.7], ref), 3), colour_score(ref[::-1], ref) < 1.5
    (3.0, True)
    """
    m = np.log(np.maximum(measured, 1e-4))
    r = np.log(np.maximum(reference, 1e-4))
    lum_m, lum_r = m.mean(axis=1), r.mean(axis=1)
    return (_corr(lum_m, lum_r) + _corr(m[:, 0] - m[:, 1], r[:, 0] - r[:, 1])
            + _corr(m[:, 2] - m[:, 1], r[:, 2] - r[:, 1]))


def _orientations(rows: int, columns: int):
    """Chart (row, column) -> lattice offsets for the four rotations and their four mirror images,
    with the window's size and whether the chart is mirrored."""
    r, c = np.divmod(np.arange(rows * columns), columns)
    turns = [
        ((columns, rows), np.column_stack([c, r])),
        ((columns, rows), np.column_stack([columns - 1 - c, rows - 1 - r])),
        ((rows, columns), np.column_stack([rows - 1 - r, c])),
        ((rows, columns), np.column_stack([r, columns - 1 - c])),
    ]
    # a mirror image: the lattice's first axis reversed
    return [(size, offsets, False) for size, offsets in turns] + [
        (size, np.column_stack([size[0] - 1 - offsets[:, 0], offsets[:, 1]]), True) for size, offsets in turns]


@dataclass(frozen=True)
class _Segments:
    """The candidate patches of a view and their groups (shared by every layout searched for)."""

    small: np.ndarray
    scale: float
    cand: np.ndarray
    groups: list
    near: np.ndarray


def _segment(view: np.ndarray, flat: bool) -> _Segments:
    import cv2

    scale = min(1.0, _MAX_SIDE / max(view.shape[:2]))
    small = view if scale == 1.0 else cv2.resize(view, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    cand = _candidates(small, flat)
    groups, near = _groups(cand) if len(cand) >= 8 else ([], np.zeros((0, 0), dtype=bool))
    return _Segments(small, scale, cand, groups, near)


#: The share of a chart's patches the segmentation must see (and at least 8).
MIN_PATCH_SHARE = 0.25


def find_chart_segmentation(
    view: np.ndarray, reference_RGB: np.ndarray, rows: int = 4, columns: int = 6, *, cache: dict | None = None
) -> SegmentationResult | None:
    """Find a ``rows x columns`` chart on an 8-bit view by segmentation (see the module docstring).

    Parameters
    ----------
    view
        ``(H, W, 3)`` uint8 sRGB-encoded RGB (:func:`detection_view`).
    reference_RGB
        ``(rows * columns, 3)`` the chart's linear RGB (any RGB space with
        positive values: only orderings of log ratios are used).
    cache
        A dict kept between calls on the same view (searching it for several
        layouts): its segmentations are made once.

    Returns
    -------
    SegmentationResult or None
        ``None`` when no group of patches forms the chart.
    """
    cache = {} if cache is None else cache
    for flat in (False, True):
        if flat not in cache:
            cache[flat] = _segment(view, flat)
        found = _search(cache[flat], reference_RGB, rows, columns)
        if found is not None:
            return found
    return None


def _search(seg: _Segments, reference_RGB: np.ndarray, rows: int, columns: int) -> SegmentationResult | None:
    """The best placement of the chart in the lattices of a view's segmentation (module docstring, step 4)."""
    small, scale, cand = seg.small, seg.scale, seg.cand
    if len(cand) < 8:
        return None
    linear = np.power(small.astype(np.float64) / 255.0, 2.2)
    reference_RGB = np.asarray(reference_RGB, dtype=np.float64)
    least = max(8, int(np.ceil(MIN_PATCH_SHARE * rows * columns)))
    best = None
    for members in seg.groups[:4]:
        if len(members) < least:
            continue
        found = _lattice(cand, members, seg.near)
        if found is None:
            continue
        ids, lattice, H, pitch = found
        lo, hi = lattice.min(axis=0), lattice.max(axis=0)
        radius = max(1, int(0.15 * pitch))
        height, width = small.shape[:2]
        for (wp, wq), offsets, mirrored in _orientations(rows, columns):
            for p0 in range(hi[0] - wp + 1, lo[0] + 1):
                for q0 in range(hi[1] - wq + 1, lo[1] + 1):
                    inside = ((lattice[:, 0] >= p0) & (lattice[:, 0] < p0 + wp)
                              & (lattice[:, 1] >= q0) & (lattice[:, 1] < q0 + wq))
                    if best is not None and int(inside.sum()) < best[0][0]:
                        continue
                    cells = offsets + [p0, q0]
                    centres = _project(H, cells.astype(np.float64))
                    x, y = np.round(centres).astype(int).T
                    if x.min() < radius or y.min() < radius or x.max() >= width - radius or y.max() >= height - radius:
                        continue
                    measured = np.array([linear[yy - radius: yy + radius + 1, xx - radius: xx + radius + 1]
                                         .reshape(-1, 3).mean(axis=0) for xx, yy in zip(x, y)])
                    score = colour_score(measured, reference_RGB)
                    key = (int(inside.sum()), score)
                    if best is None or key > best[0]:
                        lookup = {tuple(cell): k for k, cell in enumerate(cells.tolist())}
                        index = np.array([lookup.get(tuple(cell), -1) for cell in lattice.tolist()])
                        pts = cand[ids, :2]
                        ok = index >= 0
                        best = (key, (pts[ok] + 0.5) / scale - 0.5, index[ok])
    if best is None or best[0][0] < least or best[0][1] < MIN_COLOUR_SCORE:
        return None
    (count, score), centres, index = best
    return SegmentationResult(centres, index, len(cand), float(score))
