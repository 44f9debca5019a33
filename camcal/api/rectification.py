"""``camcal.rectify``: 2 or N views of a rig onto one image plane, with their images and report, as ``rectify``."""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from camcal.base.errors import CamcalError

if TYPE_CHECKING:
    from camcal.geometry.rectify import Matches, RectificationResult
    from camcal.geometry.rectify.sigma import PairSigma
    from camcal.model.rig import Rig

__all__ = ["METHODS", "Rectification", "rectify"]

#: ``method`` of :func:`rectify`: from the calibration, or from point matches alone (Hartley 1999).
METHODS = ("camera", "hartley")


@dataclass(frozen=True)
class Rectification:
    """What :func:`rectify` computed and wrote.

    Attributes
    ----------
    result : RectificationResult
        Per camera ``{H, K_rect, image_size}`` (:class:`camcal.geometry.rectify.RectificationResult`), its rig and
        residual vertical disparity.
    pairs : tuple of PairSigma
        With ``sigma=True``: each pair of consecutive cameras' vertical-disparity (and depth) sigma.
    images : tuple of Path
        The rectified images written (``write/<camera>/<file name>``).
    sigma_files : tuple of Path
        The sigma EXRs written.
    report_files : tuple of Path
        ``rectification.json`` and the report page's files.
    """

    result: RectificationResult
    pairs: tuple[PairSigma, ...] = ()
    images: tuple[Path, ...] = ()
    sigma_files: tuple[Path, ...] = ()
    report_files: tuple[Path, ...] = ()

    @property
    def rig(self) -> Rig:
        """The rectified rig: each camera with its rectification."""
        return self.result.rig

    def save(self, path: str | os.PathLike) -> Path:
        """Write the rectified rig (atomically); its path."""
        return self.rig.save(path)

    def lines(self) -> list[str]:
        """What ``rectify`` prints about the result: its summary and each pair's sigma."""
        return [self.result.summary(), *(pair.describe() for pair in self.pairs)]

    def figures(self) -> dict:
        """The figures of ``rectify --json``."""
        figures = self.result.to_report()
        if self.pairs:
            figures["sigma"] = [pair.to_dict() for pair in self.pairs]
        return figures


def rectify(
    rig: str | os.PathLike | Rig,
    *,
    method: str = "camera",
    refine: bool = False,
    images: Mapping[str, str | os.PathLike | Sequence[str | os.PathLike]] | None = None,
    every: int = 1,
    matches: str | os.PathLike | Matches | None = None,
    alpha: float = 0.0,
    max_fov_deg: float | None = None,
    out: str | os.PathLike | None = None,
    write: str | os.PathLike | None = None,
    report: str | os.PathLike | None = None,
    sigma: bool = False,
    distance: float | None = None,
) -> Rectification:
    """Rectify a rig's cameras onto one image plane (``camcal rectify``).

    Stores per camera ``{H, K_rect, image_size}``, ``H`` mapping UNDISTORTED
    original pixels to rectified pixels. ``method="camera"`` uses the
    calibration (with ``refine``: the N-view refinement of Nozick 2011 on
    matches); ``"hartley"`` uses only point matches (Hartley 1999). Matches
    come from ``matches`` or from SIFT on the first image of each camera's
    ``images`` (of a video: its frame 0). The rig, the images and the report
    are written together: all of them or none.

    Parameters
    ----------
    rig : path or Rig
        A calibrated rig.
    method : {"camera", "hartley"}
    refine : bool
        ``method="camera"``: refine on matches (Nozick 2011).
    images : mapping of str to (glob, video or image files), optional
        Images per camera, e.g. ``{"left": "L/*.png", "right": "R/*.png"}``, or a video per camera; with two or
        more, only these cameras are rectified.
    every : int
        Videos: frames 0, N, 2N...
    matches : path or Matches, optional
        Point matches in original pixels (CSV ``camera_a,u_a,v_a,camera_b,u_b,v_b``).
    alpha : float
        0: only pixels all views see; 1: every source pixel.
    max_fov_deg : float, optional
        Widest full angle about the rectified viewing direction (default: 120 with a kannala-brandt fisheye).
    out : path, optional
        The rectified ``*.rig.json`` to write.
    write : path, optional
        A folder for the rectified images (``write/<camera>/``); needs ``images``.
    report : path, optional
        A folder for ``rectification.json`` and the page ``index.html``.
    sigma : bool
        ``method="camera"`` without ``refine``: per pair of consecutive cameras, the EXRs of the vertical
        disparity's sigma (and with ``distance``, the depth's) into ``write`` (or ``report``).
    distance : float, optional
        With ``sigma``: in the rig's units (default: infinity).

    Returns
    -------
    Rectification

    Raises
    ------
    CamcalError
        Bad input (one line naming it); nothing is written then.
    """
    from camcal.base.atomic import final_path, output_folder
    from camcal.base.globs import expand_glob
    from camcal.geometry.rectify import RectifyWarper, rectify as rectify_rig
    from camcal.io.matches import read_matches_csv
    from camcal.io.video import is_video, video_info
    from camcal.model.rig import Rig
    from camcal.pipelines.rectify import match_image_files, write_rectified

    images = dict(images or {})
    if method not in METHODS:
        raise CamcalError(f"unknown method {method!r}, expected one of: {', '.join(METHODS)}")
    if not 0.0 <= alpha <= 1.0:
        raise CamcalError(f"--alpha must be in [0, 1], got {alpha}")
    if write and not images:
        raise CamcalError("--write needs --images NAME=GLOB for the cameras to rectify")
    if sigma and not (write or report):
        raise CamcalError("--sigma needs --write DIR or --report DIR for its EXRs")
    if sigma and (method != "camera" or refine):
        raise CamcalError("--sigma needs --method camera without --refine (a rotation of the calibrated cameras)")
    rig = rig if isinstance(rig, Rig) else Rig.load(rig)
    for name in images:
        rig.camera(name)
    if every < 1:
        raise CamcalError(f"--every must be 1 or more, got {every}")
    files = {name: [os.fspath(value)] if isinstance(value, (str, os.PathLike)) and is_video(os.fspath(value))
             else expand_glob("--images", name, os.fspath(value)) if isinstance(value, (str, os.PathLike))
             else [os.fspath(path) for path in value] for name, value in images.items()}
    for name, listed in files.items():
        if not listed:
            raise CamcalError(f"--images {name}: no image given")
        if is_video(listed[0]):
            video_info(listed[0])  # decodable, before anything is computed or written
    names = list(files) if len(files) >= 2 else None
    if matches is not None and isinstance(matches, (str, os.PathLike)):
        matches = read_matches_csv(matches)
    elif matches is None and files and (method == "hartley" or refine):
        matches = match_image_files(rig, {name: listed[0] for name, listed in files.items()})
    solver = {"camera": "Nozick 2011" if refine else "camera", "hartley": "Hartley 1999"}[method]
    result = rectify_rig(rig, solver, matches, names, alpha, max_fov_deg)
    pairs = []
    if sigma:
        from camcal.geometry.rectify.sigma import rectified_pair_sigma

        pairs = [rectified_pair_sigma(result.rig.camera(a), result.rig.camera(b), distance, units=rig.units)
                 for a, b in zip(result.names, result.names[1:])]
    written, sigma_files, reports = [], [], []
    sigma_dir = final_dir = None
    with output_folder(write) as write_dir, output_folder(report) as report_dir:
        if write_dir is not None:
            warper = RectifyWarper(result.rig)
            for name in result.names:
                written += write_rectified(warper, name, files.get(name, []), write_dir, every)
        links = {}
        if pairs:
            from camcal.io.stmap import write_sigma_map

            sigma_dir, final_dir = (write_dir, write) if write_dir is not None else (report_dir, report)
            for pair in pairs:
                for kind, values in (("vertical", pair.vertical_px), ("depth", pair.depth)):
                    if values is None:  # depth at infinity
                        continue
                    path = write_sigma_map(sigma_dir / f"{pair.first}-{pair.second}_{kind}_sigma.exr", values)
                    sigma_files.append(path)
                    if report:
                        links[pair.first, pair.second, kind] = os.path.relpath(final_path(path, sigma_dir, final_dir),
                                                                               report)
        if report_dir is not None:
            from camcal.base.jsonfile import write_json
            from camcal.report.rectification import write_report

            write_json(report_dir / "rectification.json", result.to_report())
            reports = [report_dir / "rectification.json", *write_report(result, report_dir, pairs, links)]
        if out is not None:
            result.rig.save(out)
    return Rectification(result, tuple(pairs), tuple(final_path(path, write_dir, write) for path in written),
                         tuple(final_path(path, sigma_dir, final_dir) for path in sigma_files),
                         tuple(final_path(path, report_dir, report) for path in reports))
