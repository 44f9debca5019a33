"""camcal's 3DE models against the LDPK's own C++: random cases, the compiled driver, the reference table.

Run as a script to regenerate ``tests/model/data/ldpk_reference.txt``::

    CAMCAL_LDPK_DIR=/path/to/ldpk python tests/model/ldpk_reference.py "LDPK 2.0 (source, commit)"

``CAMCAL_LDPK_DIR`` is an LDPK source tree (its ``include/ldpk`` headers);
``ldpk_driver.cpp`` beside this file is compiled against it with ``g++``.
Points are exchanged in LDPK's unit coordinates (``[0, 1]^2`` over the
image, y up); camcal's pixels are ``u = x_unit W - 1/2``,
``v = (1 - y_unit) H - 1/2`` (:mod:`camcal.model.tde4`).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from camcal.model import tde4
from camcal.model.distortion import Distortion

HERE = Path(__file__).resolve().parent
DRIVER_SOURCE = HERE / "ldpk_driver.cpp"
TABLE = HERE / "data" / "ldpk_reference.txt"
LDPK_DIR_VARIABLE = "CAMCAL_LDPK_DIR"
IMAGE_SIZES = ((1920, 1080), (2048, 1556), (1280, 960), (4096, 1716))
#: Parameter ranges of the random cases (camcal key -> (low, high)); keys not listed keep LDPK's default.
RANGES = {
    "3de-classic": {"distortion": (-0.15, 0.15), "anamorphic_squeeze": (0.5, 2.0), "curvature_x": (-0.05, 0.05),
                    "curvature_y": (-0.05, 0.05), "quartic_distortion": (-0.05, 0.05)},
    "3de4-radial-deg4": {"c2": (-0.06, 0.15), "u2": (-0.02, 0.02), "v2": (-0.02, 0.02), "c4": (-0.02, 0.04),
                         "u4": (-0.01, 0.01), "v4": (-0.01, 0.01), "cylindric_direction_deg": (-90.0, 90.0),
                         "cylindric_bending": (-0.1, 0.1)},
    "3de4-anamorphic-deg4": {**{f"c{axis}02": (-0.15, 0.15) for axis in "xy"},
                             **{f"c{axis}22": (-0.05, 0.05) for axis in "xy"},
                             **{f"c{axis}{term}": (-0.03, 0.03) for axis in "xy" for term in ("04", "24", "44")},
                             "lens_rotation_deg": (-2.0, 2.0), "squeeze_x": (0.9, 1.1), "squeeze_y": (0.9, 1.1)},
    "3de4-fisheye-deg8": {"c2": (-0.1, 0.1), "c4": (-0.03, 0.03), "c6": (-0.01, 0.01), "c8": (-0.003, 0.003)},
}
PIXEL_ASPECTS = (1.0, 4.0 / 3.0, 2.0)


@dataclass(frozen=True)
class Case:
    """One lens, one direction, points in LDPK unit coordinates."""

    model: str
    direction: str  # "undistort" (LDPK's model function, distorted -> undistorted) or "distort"
    image_size: tuple[int, int]
    camera: tde4.LdpkCamera
    values: tuple[float, ...]  # in LDPK's parameter order
    points_unit: np.ndarray

    @property
    def params(self) -> dict[str, float]:
        """camcal's parameters: the model's, and the film back in pixels."""
        keys = [p.key for p in tde4.LDPK_PARAMETERS[self.model]]
        return {**dict(zip(keys, self.values)), "filmback_width_px": float(self.image_size[0]),
                "filmback_height_px": float(self.image_size[1])}

    @property
    def K(self) -> np.ndarray:
        return self.camera.camera_matrix(self.image_size)


def random_case(model: str, direction: str, rng: np.random.Generator, n_points: int) -> Case:
    """A random lens of ``model`` on a random film back, with points spread over the image."""
    width, height = IMAGE_SIZES[rng.integers(len(IMAGE_SIZES))]
    pixel_aspect = 1.0 if model == "3de4-fisheye-deg8" else float(PIXEL_ASPECTS[rng.integers(len(PIXEL_ASPECTS))])
    centre = np.array([(width - 1) / 2, (height - 1) / 2]) + rng.uniform(-0.03, 0.03, 2) * (width, height)
    if model == "3de4-fisheye-deg8":  # focal over half-diagonal 0.9 .. 1.4: the image corners within 75 degrees
        fx = rng.uniform(0.9, 1.4) * 0.5 * np.hypot(width, height)
    else:
        fx = rng.uniform(0.5, 1.5) * width
    K = np.array([[fx, 0.0, centre[0]], [0.0, fx * pixel_aspect, centre[1]], [0.0, 0.0, 1.0]])
    camera = tde4.LdpkCamera.from_camera_matrix(K, (width, height), rng.uniform(1.0, 4.0))
    values = tuple(float(rng.uniform(*RANGES[model][p.key])) if p.key in RANGES[model] else p.default
                   for p in tde4.LDPK_PARAMETERS[model])
    return Case(model, direction, (width, height), camera, values, rng.uniform(0.0, 1.0, (n_points, 2)))


def random_cases(seed: int, lenses_per_direction: int, n_points: int) -> list[Case]:
    """Random cases of every model, both directions."""
    rng = np.random.default_rng(seed)
    return [random_case(model, direction, rng, n_points) for model in tde4.TDE4_MODELS
            for direction in ("undistort", "distort") for _ in range(lenses_per_direction)]


def pixels_from_unit(points_unit: np.ndarray, image_size: tuple[int, int]) -> np.ndarray:
    width, height = image_size
    return np.column_stack([points_unit[:, 0] * width - 0.5, (1.0 - points_unit[:, 1]) * height - 0.5])


def camcal_unit(case: Case) -> np.ndarray:
    """camcal's answer to ``case`` (its :class:`~camcal.model.distortion.Distortion`) in LDPK unit coordinates."""
    width, height = case.image_size
    lens = Distortion(case.model, case.params)
    function = lens.undistort if case.direction == "undistort" else lens.distort
    out = function(pixels_from_unit(case.points_unit, case.image_size), case.K)
    return np.column_stack([(out[:, 0] + 0.5) / width, 1.0 - (out[:, 1] + 0.5) / height])


def dn_difference(case: Case, a_unit: np.ndarray, b_unit: np.ndarray) -> np.ndarray:
    """Distance between two answers in diagonally normalised units (the film back's half-diagonal)."""
    a = tde4.dn_from_pixels(pixels_from_unit(a_unit, case.image_size), case.K, case.params)
    b = tde4.dn_from_pixels(pixels_from_unit(b_unit, case.image_size), case.K, case.params)
    return np.hypot(*(a - b).T)


def compile_driver(ldpk_dir: Path, out_dir: Path) -> Path:
    """``ldpk_driver.cpp`` compiled against the LDPK headers in ``ldpk_dir/include``."""
    compiler = shutil.which("g++") or shutil.which("c++")
    if compiler is None:
        raise RuntimeError("no C++ compiler (g++ or c++) on PATH")
    binary = out_dir / "ldpk_driver"
    subprocess.run([compiler, "-O2", "-std=c++11", "-w", "-I", str(ldpk_dir / "include"), str(DRIVER_SOURCE),
                    "-o", str(binary), "-pthread"], check=True, capture_output=True, text=True)
    return binary


def ldpk_names(driver: Path, model: str) -> list[str]:
    """The driver's LDPK model name followed by its parameter names."""
    return subprocess.run([str(driver), "names", model], check=True, capture_output=True, text=True).stdout.splitlines()


def run_driver(driver: Path, cases: list[Case]) -> list[np.ndarray]:
    """LDPK's answers (unit coordinates) to every case."""
    lines = []
    for case in cases:
        camera = case.camera.builtin_parameters()
        lines.append(f"{case.model} {case.direction} {len(case.points_unit)}")
        lines.append(" ".join(repr(camera[name]) for name in tde4.BUILTIN_PARAMETERS))
        lines.append(" ".join([str(len(case.values)), *map(repr, case.values)]))
        lines += [f"{x!r} {y!r}" for x, y in case.points_unit.tolist()]
    out = subprocess.run([str(driver)], input="\n".join(lines) + "\n", check=True, capture_output=True, text=True).stdout
    values = np.array(out.split(), dtype=np.float64).reshape(-1, 2)
    answers, start = [], 0
    for case in cases:
        answers.append(values[start:start + len(case.points_unit)])
        start += len(case.points_unit)
    return answers


def write_table(path: Path, cases: list[Case], answers: list[np.ndarray], source: str) -> None:
    """The reference table: one row per point, LDPK's inputs and output at full precision."""
    header = [
        "# LDPK reference values for camcal's 3DE lens models (tests/model/test_tde4.py reads this file).",
        f"# Generated by tests/model/ldpk_reference.py: ldpk_driver.cpp compiled against {source},",
        "# the LDPK plugin classes' own undistort() / distort() on random lenses (seed 20261129).",
        "# Columns: model direction width height, LDPK's built-ins (" + " ".join(tde4.BUILTIN_PARAMETERS) + "),",
        "# n and the model's n parameters in LDPK's order, then x_in y_in x_out y_out in LDPK unit coordinates",
        "# ([0, 1]^2 over the image, y up). direction: undistort (distorted -> undistorted) or distort.",
    ]
    rows = []
    for case, answer in zip(cases, answers):
        camera = case.camera.builtin_parameters()
        fixed = [case.model, case.direction, str(case.image_size[0]), str(case.image_size[1]),
                 *(repr(camera[name]) for name in tde4.BUILTIN_PARAMETERS), str(len(case.values)),
                 *map(repr, case.values)]
        rows += [" ".join([*fixed, *map(repr, (*p, *q))]) for p, q in zip(case.points_unit.tolist(), answer.tolist())]
    path.write_text("\n".join(header + rows) + "\n")


def read_table(path: Path) -> list[tuple[Case, np.ndarray]]:
    """Each row of :func:`write_table` as a one-point case and LDPK's answer."""
    out = []
    for line in path.read_text().splitlines():
        if not line or line.startswith("#"):
            continue
        fields = line.split()
        model, direction, width, height = fields[0], fields[1], int(fields[2]), int(fields[3])
        camera = tde4.LdpkCamera(*map(float, fields[4:10]))
        n = int(fields[10])
        values = tuple(map(float, fields[11:11 + n]))
        x_in, y_in, x_out, y_out = map(float, fields[11 + n:15 + n])
        case = Case(model, direction, (width, height), camera, values, np.array([[x_in, y_in]]))
        out.append((case, np.array([[x_out, y_out]])))
    return out


def main(argv: list[str]) -> int:
    if len(argv) != 2 or LDPK_DIR_VARIABLE not in os.environ:
        print(__doc__, file=sys.stderr)
        return 2
    import tempfile

    with tempfile.TemporaryDirectory() as folder:
        driver = compile_driver(Path(os.environ[LDPK_DIR_VARIABLE]), Path(folder))
        cases = random_cases(seed=20261129, lenses_per_direction=4, n_points=5)
        write_table(TABLE, cases, run_driver(driver, cases), argv[1])
    print(f"wrote {TABLE}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv))
