"""What a solved plate's own feature tracks say about its focal length, with the renderer's true cameras held.

A solve's focal error has two possible sources: the features (their locations
biased so that they imply another focal length whatever the poses) or the
estimate (the focal length trading off against the poses, as on a sideways
dolly). This separates them on a rendered plate of ``bench_plates.py``: every
track of the solve's model (``OUT/sparse/best``, pixels in COLMAP's convention)
is triangulated again with the TRUE poses and the true lens
(``bench_plates.K_TRUE``, ``bench_plates.LENS``) at focal lengths around the
truth, and the focal length whose triangulated tracks leave the least squared
reprojection error is printed (a parabola through the lowest three of a
grid of 0.1 % steps). Near 0 %: the features are unbiased in scale, and a focal error of
the solve comes from the poses. Also printed: the residuals' mean radial
component by radius, and their correlation along the tracks (the same point
``lag`` frames later), which no covariance of independent errors models.

Usage: ``python bench/plate_features.py OUT TRUTH.json`` with ``OUT`` the
folder of a ``camcal.solve`` of the plate (its images staged as
``plate/000000.png``..., frame ``--first`` + index) and ``TRUTH.json`` the
render's truth (``bench_plates.render_shot``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

sys.path.insert(0, str(Path(__file__).parent))
from bench_plates import FIRST, K_TRUE, LENS  # noqa: E402

from camcal.model.camera import pixels_from_colmap  # noqa: E402

#: observations farther than this from the true cameras' reprojection are mismatches, left out.
OUTLIER_PX = 1.0
GRID = np.linspace(-0.006, 0.006, 13)  # relative focal changes tried


class Tracks:
    """Every observation of the model's points with its frame's true pose."""

    def __init__(self, model: Path, truth: Path, first: int) -> None:
        import pycolmap

        frames = {int(k): (np.array(v["R"]), np.array(v["c"])) for k, v in json.loads(truth.read_text())["frames"].items()}
        reconstruction = pycolmap.Reconstruction(model)
        point, frame, xy = [], [], []
        for n, point3D in enumerate(reconstruction.points3D.values()):
            for element in point3D.track.elements:
                image = reconstruction.images[element.image_id]
                point.append(n)
                frame.append(first + int(Path(image.name).stem))
                xy.append(image.points2D[element.point2D_idx].xy)
        self.point, self.frame = np.array(point), np.array(frame)
        self.xy = pixels_from_colmap(np.array(xy))
        self.n_points = int(self.point.max()) + 1
        self.R = np.array([frames[f][0] for f in self.frame])
        self.c = np.array([frames[f][1] for f in self.frame])
        self.keep = np.ones(len(self.xy), dtype=bool)

    def project(self, X: NDArray[np.float64], K: NDArray[np.float64]) -> NDArray[np.float64]:
        return LENS.project_rays(np.einsum("nij,nj->ni", self.R, X[self.point] - self.c), K)

    def triangulate(self, K: NDArray[np.float64]) -> NDArray[np.float64]:
        """Each point from its kept observations: the rays' closest point, then 4 Gauss-Newton steps."""
        weight = self.keep.astype(float)
        rays = np.einsum("nji,nj->ni", self.R, LENS.rays_from_pixels(self.xy, K))
        rays /= np.linalg.norm(rays, axis=1, keepdims=True)
        P = (np.eye(3)[None] - rays[:, :, None] * rays[:, None, :]) * weight[:, None, None]
        A, b = np.zeros((self.n_points, 3, 3)), np.zeros((self.n_points, 3))
        np.add.at(A, self.point, P)
        np.add.at(b, self.point, np.einsum("nij,nj->ni", P, self.c))
        X = np.linalg.solve(A + 1e-12 * np.eye(3), b[..., None])[..., 0]
        for _ in range(4):
            r = (self.project(X, K) - self.xy) * weight[:, None]
            J = np.zeros((len(r), 2, 3))
            for k in range(3):
                J[:, :, k] = ((self.project(X + 1e-6 * np.eye(3)[k], K) - self.xy) * weight[:, None] - r) / 1e-6
            H, g = np.zeros((self.n_points, 3, 3)), np.zeros((self.n_points, 3))
            np.add.at(H, self.point, np.einsum("nki,nkj->nij", J, J))
            np.add.at(g, self.point, np.einsum("nki,nk->ni", J, r))
            X = X - np.linalg.solve(H + 1e-9 * np.eye(3), g[..., None])[..., 0]
        return X

    def residuals(self, relative_focal: float = 0.0) -> NDArray[np.float64]:
        K = K_TRUE.copy()
        K[0, 0] = K[1, 1] = K_TRUE[0, 0] * (1 + relative_focal)
        return self.project(self.triangulate(K), K) - self.xy


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("out", type=Path, help="the solve's output folder")
    parser.add_argument("truth", type=Path, help="the render's truth.json")
    parser.add_argument("--first", type=int, default=FIRST, help=f"the plate's first frame number (default {FIRST})")
    parser.add_argument("--model", default="sparse/best", help="the model under OUT (default sparse/best)")
    args = parser.parse_args()
    tracks = Tracks(args.out / args.model, args.truth, args.first)
    error = np.linalg.norm(tracks.residuals(), axis=1)
    tracks.keep = error < OUTLIER_PX
    tracks.keep &= np.bincount(tracks.point[tracks.keep], minlength=tracks.n_points)[tracks.point] >= 3
    print(f"{tracks.n_points} points, {len(tracks.xy)} observations ({int(tracks.keep.sum())} kept: within "
          f"{OUTLIER_PX} px of the true cameras, tracks of 3 or more)")
    costs = np.array([np.sum(tracks.residuals(s)[tracks.keep] ** 2) for s in GRID])
    lowest = int(np.clip(np.argmin(costs), 1, len(GRID) - 2))
    curvature, slope, _ = np.polyfit(GRID[lowest - 1:lowest + 2], costs[lowest - 1:lowest + 2], 2)
    residual = tracks.residuals()
    kept = residual[tracks.keep]
    print(f"with the true poses and lens: RMS {np.sqrt(np.mean(kept ** 2)):.4f} px at the true focal length; "
          f"the features' own focal length {-slope / (2 * curvature) * 100:+.4f} % of the truth")
    offset = tracks.xy[tracks.keep] - K_TRUE[:2, 2]
    radius = np.linalg.norm(offset, axis=1)
    radial = np.sum(kept * offset / radius[:, None], axis=1)
    for start in range(0, int(radius.max()) + 1, 60):
        inside = (radius >= start) & (radius < start + 60)
        if inside.sum() >= 100:
            print(f"  radius {start:3d}-{start + 60:3d} px: mean radial residual {radial[inside].mean():+.4f} px "
                  f"({int(inside.sum())} observations)")
    index = {(int(p), int(f)): n for n, (p, f) in enumerate(zip(tracks.point, tracks.frame))}
    for lag in (1, 5, 20, 40):
        pairs = np.array([(n, index[p, f + lag]) for (p, f), n in index.items()
                          if (p, f + lag) in index and tracks.keep[n] and tracks.keep[index[p, f + lag]]])
        if len(pairs) < 100:
            continue
        earlier, later = residual[pairs[:, 0]], residual[pairs[:, 1]]
        x, y = (np.corrcoef(earlier[:, k], later[:, k])[0, 1] for k in (0, 1))
        print(f"  residual correlation along the tracks, {lag:2d} frames apart: x {x:+.3f}, y {y:+.3f} "
              f"({len(pairs)} pairs)")


if __name__ == "__main__":
    main()
