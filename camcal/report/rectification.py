"""The ``camcal rectify --report`` page: the rectification's figures and, with ``--sigma``, its sigma maps.

``index.html`` (static, offline: inline CSS, images by relative path) shows

- the rectification's summary (:meth:`RectificationResult.summary`: size,
  focal length, disparity on matches, each camera's deformation);
- per pair of consecutive cameras ``A-B`` (:class:`~camcal.geometry.rectify.sigma.PairSigma`),
  the sigma of the vertical disparity (rectified pixels) and, at a given
  distance, of the depth (rig units), each a heat map drawn by
  :func:`camcal.report.sigma.plot_sigma_map` (viridis from 0 to the worst
  value, colour bar with the unit, NaN pixels grey) pixel for pixel with
  ``A``'s rectified image, and a table of the worst, median and corner
  values (``data-value`` holds each figure unrounded), with the EXR each
  map was written to.

The maps are the first-order propagation of the calibration's covariance
(Hartley & Zisserman 2004, section 5.2): sampling noise, not model error.
"""

from __future__ import annotations

import html
import math
import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from urllib.parse import quote

from camcal.base.atomic import atomic_write_text
from camcal.geometry.rectify import RectificationResult
from camcal.geometry.rectify.sigma import PairSigma
from camcal.geometry.uncertainty import SigmaSummary
from camcal.report.sigma import plot_sigma_map
from camcal.report.volume import PAGE_STYLE

__all__ = ["write_report"]

#: The maps of a pair, in page order: key (``sigma_<key>_A-B.png``), title.
_KINDS = (("vertical", "vertical disparity sigma"), ("depth", "depth sigma"))

_STYLE = PAGE_STYLE + " figure{display:inline-block;margin:0 1em 1em 0;vertical-align:top}"


def _number(value: float) -> str:
    """A table cell holding ``value`` rounded, and unrounded in ``data-value`` (empty for NaN: no source pixel)."""
    if not math.isfinite(value):
        return "<td class='num' data-value=''>-</td>"
    return f"<td class='num' data-value='{value!r}'>{value:.4g}</td>"


def _sigma_row(pair: PairSigma, kind: str, summary: SigmaSummary, exr: str | None) -> str:
    where = "infinity" if summary.distance is None else f"{summary.distance:g} {pair.units}"
    link = "-"
    if exr is not None:
        link = f"<a href='{html.escape(quote(Path(exr).as_posix()))}'>{html.escape(Path(exr).name)}</a>"
    corners = "".join(_number(value) for value in summary.corners_px)
    return (f"<tr id='sigma-{html.escape(pair.first)}-{html.escape(pair.second)}-{kind}'>"
            f"<td>{html.escape(pair.first)}-{html.escape(pair.second)}</td><td>{html.escape(summary.label)}</td>"
            f"<td>{html.escape(where)}</td><td>{html.escape(summary.unit)}</td>"
            f"{_number(summary.worst_px)}{_number(summary.median_px)}{corners}<td>{link}</td></tr>")


def write_report(result: RectificationResult, out_dir: str | os.PathLike, pairs: Sequence[PairSigma] = (),
                 exr_links: Mapping[tuple[str, str, str], str] | None = None) -> list[Path]:
    """The rectification page ``index.html`` and each pair's sigma heat maps, written atomically into ``out_dir``.

    Parameters
    ----------
    result : RectificationResult
        The rectification.
    out_dir : path
        The report folder.
    pairs : sequence of PairSigma
        The sigma maps of consecutive camera pairs (``rectify --sigma``); none: the page says how to get them.
    exr_links : mapping, optional
        ``(first, second, kind)`` (kind ``"vertical"`` or ``"depth"``) -> the EXR of that map, relative to
        the page's final folder, shown as a link.

    Returns
    -------
    list of Path
        The files written: per pair ``sigma_vertical_A-B.png`` (and ``sigma_depth_A-B.png``), then ``index.html``.
    """
    directory = Path(out_dir)
    links = dict(exr_links or {})
    written, rows, figures = [], [], []
    for pair in pairs:
        maps = {"vertical": (pair.vertical_px, pair.vertical_summary()), "depth": (pair.depth, pair.depth_summary())}
        for kind, title in _KINDS:
            values, summary = maps[kind]
            if values is None:
                continue
            where = "at infinity" if pair.distance is None else f"at distance {pair.distance:g} {pair.units}"
            png = plot_sigma_map(values, directory / f"sigma_{kind}_{pair.first}-{pair.second}.png",
                                 f"{pair.first}-{pair.second}: {title} {where}", summary.unit)
            written.append(png)
            rows.append(_sigma_row(pair, kind, summary, links.get((pair.first, pair.second, kind))))
            alt = html.escape(f"{pair.first}-{pair.second} {title} heat map")
            figures.append(f"<figure><img id='map-{html.escape(pair.first)}-{html.escape(pair.second)}-{kind}' "
                           f"src='{html.escape(quote(png.name))}' alt='{alt}' width='560'></figure>")
        if not pair.cross_covariance:
            figures.append(f"<p class='note'>{html.escape(pair.first)}-{html.escape(pair.second)}: the rig file "
                           "holds no covariance between the two cameras; they were taken as independent.</p>")
    if rows:
        sigma = f"""<p>Each map is pixel for pixel with the first camera's rectified image; the colour scale runs
from 0 to the map's worst value. It propagates the calibration's covariance to first order: it covers sampling
noise, not model error.</p>
<table id="sigma"><thead><tr><th>pair</th><th>map</th><th>scene at</th><th>unit</th><th>worst</th><th>median</th>
<th>top left</th><th>top right</th><th>bottom left</th><th>bottom right</th><th>EXR</th></tr></thead>
<tbody>{''.join(rows)}</tbody></table>
<div id="maps">{''.join(figures)}</div>"""
    else:
        sigma = "<p id='sigma'>No sigma maps: run <code>camcal rectify --sigma</code> (--method camera).</p>"
    page = f"""<!DOCTYPE html>
<html lang="en"><head><meta charset="utf-8"><title>camcal: rectification of {len(result.names)} cameras</title>
<style>{_STYLE}</style></head><body>
<h1>Rectification of {len(result.names)} cameras ({html.escape(result.method)})</h1>
<pre id="summary">{html.escape(result.summary())}</pre>
<h2>Uncertainty of the rectified pairs</h2>
{sigma}
</body></html>
"""
    index = directory / "index.html"
    atomic_write_text(index, page)
    return written + [index]
