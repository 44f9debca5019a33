"""Calibration boards: definitions, parsing and detection in images.

Two kinds of planar target:

``chessboard:WxH:SQUARE``
    A chessboard with ``W x H`` INNER corners (OpenCV's pattern size) and
    squares of side ``SQUARE`` (in the board's units, e.g. metres, or 1.0
    to measure in squares). Found by ``cv2.findChessboardCorners`` (the
    fastest), falling back to ``cv2.findChessboardCornersSB`` (plain, then
    with its exhaustive and accuracy flags) when it fails or when the
    X-junction fit below rejects one of its corners (then the search at the
    same size with the fewest rejected corners is kept); all three run
    on a quarter-size copy first when the image is 800 px or more on both
    sides, then on a half-size one from 400 px, full size last; either way
    refined by ``cv2.cornerSubPix`` with a window of half-size
    ``0.45 x`` the smallest corner spacing in the image (3 to 15 px): a
    window that spans most of a square converges to the same saddle point
    whatever the start, where OpenCV's customary 5 px half-window does not
    on low-contrast images (on the real stereo pairs the right camera's
    training RMS falls from 0.29 to 0.14 px and the held-out PnP RMS from
    0.172 to 0.166 px).
``charuco:DICT:WxH:SQUARE:MARKER``
    A ChArUco board of ``W x H`` SQUARES with ArUco markers from the
    dictionary ``DICT`` (e.g. ``DICT_5X5_100``), detected with
    ``cv2.aruco.CharucoDetector``; corners may be partially visible; refined
    like a chessboard's, on the part of each square the marker leaves clear.

Boards as they are printed, options after the sizes (any order):

``:inverted`` (ChArUco)
    White markers on black: detected on the inverted image (``255 - I``).
``:legacy`` (ChArUco)
    OpenCV's legacy pattern (``CharucoBoard.setLegacyPattern(True)``, the
    layout of OpenCV < 4.6 for an even number of rows).
``:two-sided`` (ChArUco and chessboard)
    Printed on the back as the mirror image, each back corner at the same
    board point as the front one: the back's texture at board point
    ``(X, Y)`` is the front's, so a camera behind the board sees the front
    pattern mirrored. A ChArUco board is detected on the image and on its
    mirror image (``x' = W - 1 - x``); the detection with more corners is
    kept, the mirrored one's corners mapped back (``x = W - 1 - x'``) and
    keeping their ids, i.e. their board points. A chessboard looks alike
    from both sides (its detection is the same on the mirror image): its
    corners are labelled as if seen from the front, and one camera
    calibrates from either side (a mirrored labelling of a plane is another
    valid pose); in a rig, the side each view shows is decided by the
    board pose the other cameras of its frame see
    (:func:`camcal.geometry.labelling.resolve_labellings`).

Board coordinates: corner ``id`` of a chessboard is ``row * W + col`` at
``(col * square, row * square, 0)``; ChArUco corners are those of
``cv2.aruco.CharucoBoard.getChessboardCorners``. The board is the plane
``z = 0``. Pixel (0, 0) is the centre of the top-left pixel (OpenCV).

Detection over many image files, cached (:func:`camcal.pipelines.board.detect_in_images`),
is keyed by :data:`DETECTOR_SETTINGS`.

Corner order of a chessboard is made canonical so that every camera of a
rig labels the same physical corner with the same id: the board's axes
appear right-handed in the image (it is seen from its printed side), and,
when ``W + H`` is odd, the first interior square is the darker end of the
diagonal. When ``W + H`` is even the board is symmetric under a half turn
and its labelling cannot be fixed from the image: prefer boards with
``W + H`` odd (e.g. 9x6) for rigs.

References
----------
Duda, A. & Frese, U. (2018). Accurate detection and localization of
checkerboard corners for calibration. BMVC (findChessboardCornersSB).
Garrido-Jurado, S. et al. (2014). Automatic generation and detection of
highly reliable fiducial markers under occlusion. Pattern Recognition.
"""

from __future__ import annotations

import contextlib
import re
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import PurePath

import cv2
import numpy as np
from numpy.typing import NDArray

from camcal.base.errors import CamcalError
from camcal.geometry.corners import grid_spacing_px, refine_corners

__all__ = [
    "DETECTOR_SETTINGS",
    "MAX_BOARD_SIDE",
    "Board",
    "Detection",
    "DetectionReport",
    "parse_board",
    "detect_board",
    "frame_number",
    "opencv_threads_off",
    "synchronised_label",
    "video_frame_label",
]

# No CALIB_CB_NORMALIZE_IMAGE for the SB detector: its histogram equalisation bends the
# grey ramps of sharp edges and moved corners by 0.3 px, radially, in `camcal demo`'s
# rendered boards (lambda off by 24 %, fx by 0.3 %); without it they are within 0.04-0.1 px.
_SB_FLAGS = cv2.CALIB_CB_ACCURACY | cv2.CALIB_CB_EXHAUSTIVE
_CLASSIC_FLAGS = cv2.CALIB_CB_ADAPTIVE_THRESH | cv2.CALIB_CB_NORMALIZE_IMAGE
_SUBPIX_CRITERIA = (cv2.TERM_CRITERIA_EPS + cv2.TERM_CRITERIA_MAX_ITER, 100, 1e-4)
#: Images at least this large (both sides) are searched at half size first (twice as large: quarter size).
_HALF_SIZE_MIN_PX = 400
#: cornerSubPix half-window as a fraction of the smallest corner spacing, and its bounds in px.
_SUBPIX_WINDOW_FRACTION = 0.45
_SUBPIX_WINDOW_PX = (3, 15)
#: Most squares (or inner corners) per side of a board: beyond it a spec is a typo, not a print.
MAX_BOARD_SIDE = 1000
#: A refined ChArUco corner this far (px) from the detector's, and rejected by the X-junction fit, is the
#: detector's again (its own corners are within about 0.5 px: opencv/opencv#25539's bias).
_CHARUCO_JUMP_PX = 1.0
#: Fewest ChArUco corners kept in one image (a pose needs non-collinear points).
MIN_CHARUCO_CORNERS = 6
#: Part of every cache key: change it whenever detection changes what it returns.
_DETECTOR_VERSION = "reduced-classic-reduced-sb-subpix-adaptive-xfit-v10"
#: The detector's version and settings: a detection cached under others is not reused.
DETECTOR_SETTINGS = f"{_DETECTOR_VERSION}|{_SB_FLAGS}|{_CLASSIC_FLAGS}|{_SUBPIX_CRITERIA}|{cv2.__version__}"


@contextlib.contextmanager
def opencv_threads_off(active: bool = True) -> Iterator[None]:
    """OpenCV on one thread (restored after, also on errors): while camcal's own worker threads detect, and around
    its calibrations, whose parallel sums otherwise differ in the last digits from run to run (an ill-conditioned
    fit, OpenCV's thin prism, then lands in another minimum)."""
    threads = cv2.getNumThreads()
    if active:
        cv2.setNumThreads(1)
    try:
        yield
    finally:
        cv2.setNumThreads(threads)


@dataclass(frozen=True)
class Board:
    """A planar calibration target.

    Parameters
    ----------
    kind : str
        ``"chessboard"`` or ``"charuco"``.
    columns, rows : int
        Chessboard: inner corners per row and per column (OpenCV's pattern
        size). ChArUco: squares along x and y.
    square : float
        Side of one square, in the board's units.
    marker : float, optional
        ChArUco only: side of a marker, smaller than ``square``.
    dictionary : str, optional
        ChArUco only: an ``cv2.aruco`` predefined dictionary name.
    inverted : bool
        ChArUco only: white markers on black.
    two_sided : bool
        Printed on the back as the mirror image, corners at the same board points.
    legacy : bool
        ChArUco only: OpenCV's legacy pattern.

    Examples
    --------
    >>> board = parse_board("chessboard:9x6:0.025")
    >>> board.object_points.shape
    (54, 3)
    """

    kind: str
    columns: int
    rows: int
    square: float
    marker: float | None = None
    dictionary: str | None = None
    inverted: bool = False
    two_sided: bool = False
    legacy: bool = False
    object_points: NDArray[np.float64] = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if self.kind not in ("chessboard", "charuco"):
            raise CamcalError(f"unknown board kind {self.kind!r}, expected one of: chessboard, charuco")
        minimum = 2 if self.kind == "chessboard" else 3
        if self.columns < minimum or self.rows < minimum:
            what = "inner corners" if self.kind == "chessboard" else "squares"
            raise CamcalError(f"a {self.kind} needs at least {minimum}x{minimum} {what}, got {self.columns}x{self.rows}")
        if self.columns > MAX_BOARD_SIDE or self.rows > MAX_BOARD_SIDE:
            raise CamcalError(f"a {self.kind} of {self.columns}x{self.rows} is not a printable board "
                              f"(at most {MAX_BOARD_SIDE} per side)")
        if not np.isfinite(self.square) or self.square <= 0:
            raise CamcalError(f"square size must be a positive number, got {self.square!r}")
        if self.kind == "charuco":
            if self.marker is None or not np.isfinite(self.marker) or not 0 < self.marker < self.square:
                raise CamcalError(f"charuco marker size must be positive and below the square size, got {self.marker!r}")
            if not hasattr(cv2.aruco, str(self.dictionary)) or not str(self.dictionary).startswith("DICT_"):
                raise CamcalError(f"unknown ArUco dictionary {self.dictionary!r}, e.g. DICT_5X5_100")
            try:
                points = np.asarray(self.charuco_board().getChessboardCorners(), dtype=np.float64)
            except cv2.error:
                size = int(str(self.dictionary).rsplit("_", 1)[-1]) if str(self.dictionary)[-1].isdigit() else None
                raise CamcalError(f"a {self.columns}x{self.rows} charuco board needs {self.columns * self.rows // 2} "
                                  f"markers; {self.dictionary} holds {size or 'fewer'}") from None
        else:
            if self.marker is not None or self.dictionary is not None:
                raise CamcalError("marker size and dictionary apply only to charuco boards")
            if self.inverted or self.legacy:
                raise CamcalError("the inverted and legacy options apply only to charuco boards")
            col, row = np.meshgrid(np.arange(self.columns), np.arange(self.rows))
            points = np.stack([col.ravel(), row.ravel(), np.zeros(col.size)], axis=1) * self.square
        points.setflags(write=False)
        object.__setattr__(self, "object_points", points)

    @property
    def n_corners(self) -> int:
        """Number of corners with an id."""
        return len(self.object_points)

    @property
    def clear_fraction(self) -> float:
        """The part of a square around a corner free of markers (1 on a chessboard, ``0.8 (square - marker) /
        square`` on ChArUco): the corner refinement's window stays inside it."""
        return 1.0 if self.kind != "charuco" else 0.8 * (self.square - self.marker) / self.square

    def charuco_board(self) -> cv2.aruco.CharucoBoard:
        """The OpenCV board object (ChArUco only)."""
        if self.kind != "charuco":
            raise CamcalError("not a charuco board")
        dictionary = cv2.aruco.getPredefinedDictionary(getattr(cv2.aruco, str(self.dictionary)))
        board = cv2.aruco.CharucoBoard((self.columns, self.rows), self.square, self.marker, dictionary)
        board.setLegacyPattern(self.legacy)
        return board

    def spec(self) -> str:
        """The string :func:`parse_board` reads back."""
        options = "".join(f":{name}" for name, on in (("inverted", self.inverted), ("two-sided", self.two_sided),
                                                       ("legacy", self.legacy)) if on)
        if self.kind == "chessboard":
            return f"chessboard:{self.columns}x{self.rows}:{self.square:g}{options}"
        return f"charuco:{self.dictionary}:{self.columns}x{self.rows}:{self.square:g}:{self.marker:g}{options}"


#: The options each board kind takes after its sizes.
_BOARD_OPTIONS = {"chessboard": ("two-sided",), "charuco": ("inverted", "two-sided", "legacy")}


def parse_board(spec: str) -> Board:
    """Parse ``chessboard:WxH:SQUARE[:two-sided]`` or ``charuco:DICT:WxH:SQUARE:MARKER[:inverted][:two-sided][:legacy]``.

    Parameters
    ----------
    spec : str
        E.g. ``chessboard:9x6:0.025`` (9x6 inner corners, 25 mm squares),
        ``charuco:DICT_5X5_100:7x5:0.04:0.03`` or
        ``charuco:DICT_4X4_1000:4x5:0.054:0.0405:inverted:two-sided``.

    Returns
    -------
    Board
    """
    parts = str(spec).strip().split(":")
    usage = ("expected chessboard:WxH:SQUARE[:two-sided] or "
             "charuco:DICT:WxH:SQUARE:MARKER[:inverted][:two-sided][:legacy]")
    size_index = {"chessboard": 1, "charuco": 2}.get(parts[0])
    expected_len = {"chessboard": 3, "charuco": 5}.get(parts[0])
    if size_index is None or len(parts) < expected_len:
        raise CamcalError(f"bad board {spec!r}: {usage}")
    options = parts[expected_len:]
    parts = parts[:expected_len]
    allowed = _BOARD_OPTIONS[parts[0]]
    for option in options:
        if option not in allowed:
            raise CamcalError(f"bad board {spec!r}: unknown option {option!r} for a {parts[0]} "
                              f"(expected {', '.join(allowed)})")
    if len(set(options)) < len(options):
        raise CamcalError(f"bad board {spec!r}: an option is given twice")
    flags = {"inverted": "inverted" in options, "two_sided": "two-sided" in options, "legacy": "legacy" in options}
    match = re.fullmatch(r"(\d+)x(\d+)", parts[size_index])
    if not match:
        raise CamcalError(f"bad board size {parts[size_index]!r} in {spec!r}: expected WxH, e.g. 9x6")
    try:
        numbers = [float(value) for value in parts[size_index + 1 :]]
    except ValueError:
        raise CamcalError(f"bad board {spec!r}: square and marker sizes must be numbers") from None
    columns, rows = int(match.group(1)), int(match.group(2))
    if parts[0] == "chessboard":
        return Board("chessboard", columns, rows, numbers[0], **flags)
    return Board("charuco", columns, rows, numbers[0], marker=numbers[1], dictionary=parts[1], **flags)


@dataclass(frozen=True)
class Detection:
    """The board's corners found in one image.

    Attributes
    ----------
    image : str
        The image's file name (or a label).
    image_size : (int, int)
        Width, height in pixels.
    ids : ndarray of int, shape (M,)
        Corner ids (rows of :attr:`Board.object_points`), increasing.
    corners_px : ndarray, shape (M, 2)
        Corner pixels, pixel (0, 0) at the centre of the top-left pixel.
    detector : str
        ``"sb"``, ``"classic"``, ``"charuco"`` or ``"charuco-mirrored"`` (a
        two-sided board's back, found on the mirror image).
    """

    image: str
    image_size: tuple[int, int]
    ids: NDArray[np.int64]
    corners_px: NDArray[np.float64]
    detector: str


@dataclass(frozen=True)
class DetectionReport:
    """Detections over a set of images of one camera.

    Attributes
    ----------
    detections : tuple of Detection
        One per image where the board was found.
    skipped : tuple of str
        Images where it was not found (or could not be read).
    n_frames : int or None
        A video's frames decoded (None for images).
    """

    detections: tuple[Detection, ...]
    skipped: tuple[str, ...]
    n_frames: int | None = None

    @property
    def n_images(self) -> int:
        return len(self.detections) + len(self.skipped)

    def summary(self) -> str:
        """E.g. ``board found in 23 / 25 images (skipped: left07.jpg, left19.jpg)``."""
        text = f"board found in {len(self.detections)} / {self.n_images} images"
        if self.skipped:
            text += f" (skipped: {', '.join(self.skipped)})"
        return text


def _canonical_chessboard(gray: NDArray[np.uint8], corners: NDArray[np.float64], columns: int, rows: int) -> NDArray[np.float64]:
    """Reorder chessboard corners so that every camera labels them alike.

    Notes
    -----
    1. Handedness: with ``a = x_1 - x_0`` (along a row) and ``b = x_W - x_0``
       (down a column), a board seen from its printed side has
       ``a_x b_y - a_y b_x > 0`` in an image with y down; otherwise the
       rows are reversed (a mirror of the labelling).
    2. Half turn (only decidable when ``W + H`` is odd, where the two
       diagonal end squares differ in colour): the first interior square
       (corners 0, 1, W, W+1) must be darker than the last one, otherwise
       the order is reversed.
    """
    grid = corners.reshape(rows, columns, 2)
    a = grid[0, 1] - grid[0, 0]
    b = grid[1, 0] - grid[0, 0]
    if a[0] * b[1] - a[1] * b[0] < 0:
        grid = grid[:, ::-1]
    if (columns + rows) % 2 == 1:

        def mean_intensity(quad: NDArray[np.float64]) -> float:
            centre = quad.mean(axis=0)
            radius = max(1, int(0.2 * min(np.linalg.norm(quad[0] - quad[1]), np.linalg.norm(quad[0] - quad[2]))))
            x, y = int(round(centre[0])), int(round(centre[1]))
            patch = gray[max(0, y - radius) : y + radius + 1, max(0, x - radius) : x + radius + 1]
            return float(patch.mean()) if patch.size else 0.0

        first = mean_intensity(np.array([grid[0, 0], grid[0, 1], grid[1, 0], grid[1, 1]]))
        last = mean_intensity(np.array([grid[-1, -1], grid[-1, -2], grid[-2, -1], grid[-2, -2]]))
        if first > last:
            grid = grid[::-1, ::-1]
    return grid.reshape(-1, 2)


def _refine(gray: NDArray[np.uint8], corners: NDArray, grid: NDArray[np.int64], clear: float
            ) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """The X-junction fit of :func:`camcal.geometry.corners.refine_corners` (``clear``: part of a square free of
    markers): the corners and which of them the fit accepted (a rejected one is kept where it was)."""
    corners = corners.reshape(-1, 2).astype(np.float64)
    result = refine_corners(gray, corners, clear * grid_spacing_px(corners, grid))
    return result.corners_px, result.ok


def _charuco_corners(board: Board, gray: NDArray[np.uint8]):
    """ChArUco corners and ids (OpenCV's arrays, or None) and the detector's name.

    A two-sided board is also looked for on the mirror image (its back, seen
    from behind); the mirrored detection's corners are mapped back
    (``x = W - 1 - x'``) with their ids, and the one with more corners wins
    (the front on a tie, so the mirror image is not searched when the front
    shows every corner: a third of the time of a video frame).
    """
    detector = cv2.aruco.CharucoDetector(board.charuco_board())
    corners, ids, _, _ = detector.detectBoard(gray)
    found = (corners, ids, "charuco")
    every_corner = (board.columns - 1) * (board.rows - 1)
    if board.two_sided and (ids is None or len(ids) < every_corner):
        mirrored, mirrored_ids, _, _ = detector.detectBoard(np.ascontiguousarray(gray[:, ::-1]))
        if mirrored_ids is not None and len(mirrored_ids) > (0 if ids is None else len(ids)):
            mirrored = mirrored.reshape(-1, 1, 2).astype(np.float32)
            mirrored[:, 0, 0] = gray.shape[1] - 1 - mirrored[:, 0, 0]
            found = (mirrored, mirrored_ids, "charuco-mirrored")
    return found

def _search_reduced_first(gray: NDArray[np.uint8], *finders) -> Iterator[tuple[NDArray, int, int]]:
    """Run the finders in turn on a quarter-size copy (both sides >= 800 px), then half size (>= 400 px), then full size.

    Yields every success in that order: its corners mapped back to full-size pixels (pixel centres map as
    ``f x + (f - 1) / 2``), the finder's index and the reduction ``f``. A reduced copy has 4x (16x) fewer pixels: the board is
    found that much faster, and the refinement at full size makes up the accuracy.
    """
    height, width = gray.shape
    for factor in (4, 2, 1):
        if factor > 1 and min(height, width) < _HALF_SIZE_MIN_PX * factor // 2:
            continue
        image = gray if factor == 1 else cv2.resize(gray, (width // factor, height // factor), interpolation=cv2.INTER_AREA)
        for index, finder in enumerate(finders):
            found, corners = finder(image)
            if found:
                yield factor * corners + (factor - 1) / 2, index, factor


def detect_board(board: Board, image: NDArray, name: str = "image") -> Detection | None:
    """Find ``board`` in one image.

    Parameters
    ----------
    board : Board
    image : ndarray, shape (H, W) or (H, W, 3)
        8-bit grey or BGR image.
    name : str
        Label stored in the detection (the file name).

    Returns
    -------
    Detection or None
        ``None`` when the board is not found (chessboard: not every corner
        found; ChArUco: fewer than :data:`MIN_CHARUCO_CORNERS` corners).
    """
    gray = image if image.ndim == 2 else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
    if gray.dtype != np.uint8:
        raise CamcalError(f"{name}: expected an 8-bit image, got {gray.dtype}")
    if board.inverted:  # white markers on black: the detector looks for black ones
        gray = 255 - gray
    height, width = gray.shape
    if board.kind == "charuco":
        corners, ids, charuco = _charuco_corners(board, gray)
        if ids is None or len(ids) < MIN_CHARUCO_CORNERS:
            return None
        # OpenCV <= 4.12 returns ChArUco corners biased by +0.5 px (opencv/opencv#25539): refine
        # them again with cornerSubPix, which converges to the saddle point whatever the start
        detected = corners.reshape(-1, 2).astype(np.float64)
        corners = cv2.cornerSubPix(gray, corners.astype(np.float32), (5, 5), (-1, -1), _SUBPIX_CRITERIA)
        ids = ids.ravel().astype(np.int64)
        grid = np.stack([ids % (board.columns - 1), ids // (board.columns - 1)], axis=1)
        corners, ok = _refine(gray, corners, grid, board.clear_fraction)
        # on a steep view of small squares cornerSubPix can jump to a marker's corner (1.7 px off where OpenCV
        # 4.11's own corner was 0.3 px off): a corner it moved that far that the X-junction fit rejects
        # goes back to the detector's
        jumped = ~ok & (np.linalg.norm(corners - detected, axis=1) > _CHARUCO_JUMP_PX)
        corners = np.where(jumped[:, None], detected, corners)
        order = np.argsort(ids)
        return Detection(name, (width, height), ids[order], corners[order], charuco)
    pattern = (board.columns, board.rows)
    # every search on reduced copies before any at full size: SB at full size took 30 s per call on a 4K
    # frame and the classic search 45-100 s on a 2048x1536 one, where quarter-size copies take 0.1-0.6 s;
    # the refinement below works at full size
    detectors = ("classic", "sb", "sb")
    searches = _search_reduced_first(
        gray,
        lambda img: cv2.findChessboardCorners(img, pattern, flags=_CLASSIC_FLAGS),
        lambda img: cv2.findChessboardCornersSB(img, pattern, flags=0),
        lambda img: cv2.findChessboardCornersSB(img, pattern, flags=_SB_FLAGS),
    )
    col, row = np.meshgrid(np.arange(board.columns), np.arange(board.rows))
    grid_ids = np.stack([col.ravel(), row.ravel()], axis=1)
    best = None
    # A search whose corners the X-junction fit rejects (the classic search puts an outer corner of a strongly
    # bent board on the board's rim, 10-30 px off, on real fisheye and car-camera views) gives way to the next
    # search at the same size (searches at full size can take seconds); if every one leaves some corner
    # rejected, the one with the fewest is kept.
    for corners, which, factor in searches:
        if best is not None and factor != best[3]:
            break
        # The SB corners are pulled towards the image centre (0.1 px at 300 px from it, on
        # `camcal demo`'s rendered boards, with or without lens distortion): cornerSubPix
        # converges to the saddle point and removes that bias (0.0002 px left).
        grid = corners.reshape(board.rows, board.columns, 2)
        spacing = min(np.linalg.norm(np.diff(grid, axis=axis), axis=2).min() for axis in (0, 1))
        half = int(np.clip(round(_SUBPIX_WINDOW_FRACTION * spacing), *_SUBPIX_WINDOW_PX))
        corners = cv2.cornerSubPix(gray, corners.astype(np.float32), (half, half), (-1, -1), _SUBPIX_CRITERIA)
        refined, ok = _refine(gray, corners, grid_ids, board.clear_fraction)
        n_rejected = int(np.count_nonzero(~ok))
        if best is None or n_rejected < best[2]:
            best = (refined, which, n_rejected, factor)
        if n_rejected == 0:
            break
    if best is None:
        return None
    corners, which = best[:2]
    detector = detectors[which]
    corners = _canonical_chessboard(gray, corners, board.columns, board.rows)
    return Detection(name, (width, height), np.arange(board.n_corners, dtype=np.int64), corners, detector)


def video_frame_label(video: str, frame: int) -> str:
    """The name of frame ``frame`` of a video in detections: ``cam_0.mp4#12`` (read back by :func:`frame_number`)."""
    return f"{PurePath(video).name}#{int(frame)}"


def synchronised_label(name: str, number: int) -> str:
    """A view's name with the frame number it is synchronised to: ``cam_1.mp4#15@12`` (read by :func:`frame_number`)."""
    return f"{name}@{int(number)}"


def frame_number(name: str) -> int:
    """The frame number in an image's file name: the last group of digits of its stem.

    ``left07.jpg`` -> 7, ``cam2_frame_0113.png`` -> 113; a video frame's
    label (:func:`video_frame_label`) ``cam_0.mp4#12`` -> 12; a view
    synchronised by time (:func:`synchronised_label`) ``cam_1.mp4#15@12`` -> 12.
    """
    synchronised = re.fullmatch(r".+@(\d+)", str(name))
    if synchronised:
        return int(synchronised.group(1))
    video = re.fullmatch(r".*#(\d+)", str(name))
    if video:
        return int(video.group(1))
    digits = re.findall(r"\d+", PurePath(name).stem)
    if not digits:
        raise CamcalError(f"no frame number in the file name {name!r} (views of several cameras are matched by it)")
    return int(digits[-1])
