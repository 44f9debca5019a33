"""Hostile files (issue 33): each costs one line, exit 2, nothing written, and bounded memory.

Runs ``camcal`` in a child process per case and prints its exit code, its
error line and its peak resident memory (``ru_maxrss`` of the child), with
the 1 GB bound the issue sets. Run: ``python bench/bench_hostile.py``.
"""

from __future__ import annotations

import json
import resource
import struct
import subprocess
import sys
import tempfile
import zlib
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from camcal.model.rig import Rig  # noqa: E402
from camcal.synthetic import example_camera  # noqa: E402

BOUND_MB = 1024.0


def png_declaring(width: int, height: int) -> bytes:
    """A PNG signature and a valid IHDR declaring ``width`` x ``height``, then no pixels."""
    body = b"IHDR" + struct.pack(">IIBBBBB", width, height, 8, 2, 0, 0, 0)
    chunk = struct.pack(">I", 13) + body + struct.pack(">I", zlib.crc32(body))
    return b"\x89PNG\r\n\x1a\n" + chunk + struct.pack(">I", 0) + b"IEND" + struct.pack(">I", zlib.crc32(b"IEND"))


def jpeg_declaring(width: int, height: int) -> bytes:
    """SOI, JFIF APP0, a baseline SOF0 declaring ``width`` x ``height``, EOI."""
    app0 = b"\xff\xe0" + struct.pack(">H", 16) + b"JFIF\x00\x01\x01\x00\x00\x01\x00\x01\x00\x00"
    sof = b"\xff\xc0" + struct.pack(">HBHHB", 17, 8, height, width, 3) + b"\x01\x11\x00\x02\x11\x00\x03\x11\x00"
    return b"\xff\xd8" + app0 + sof + b"\xff\xd9"


def rig_with(**fields) -> str:
    data = Rig((example_camera("cam"),)).to_dict()
    data["cameras"][0].update(fields)
    return json.dumps(data)


def peak_run(argv: list[str], cwd: Path) -> tuple[int, str, float]:
    """Exit code, last stderr line and peak RSS (MB) of ``camcal argv`` in a fresh child."""
    code = ("import resource, subprocess, sys, json; "
            f"r = subprocess.run([sys.executable, '-m', 'camcal', *{argv!r}], capture_output=True, text=True); "
            "print(json.dumps([r.returncode, (r.stderr.strip().splitlines() or [''])[-1], "
            "resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss]))")
    out = subprocess.run([sys.executable, "-c", code], cwd=cwd, capture_output=True, text=True, check=True).stdout
    exit_code, line, kb = json.loads(out)
    return exit_code, line, kb / 1024.0


def main() -> int:
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        for name, content in (("png", png_declaring(200_000, 200_000)), ("jpg", jpeg_declaring(65_500, 65_500))):
            folder = root / name
            folder.mkdir()
            (folder / f"view01.{name}").write_bytes(content)
            (folder / f"view02.{name}").write_bytes(content)
        (root / "deep.rig.json").write_text('{"format": "camcal.rig", "version": 1, "cameras": '
                                            + "[" * 100_000 + "]" * 100_000 + "}")
        (root / "huge.rig.json").write_text(rig_with(image_size=[10**9, 10**9]))
        (root / "fx.rig.json").write_text(rig_with(K=[[1e308, 0.0, 959.5], [0.0, 1e308, 539.5], [0.0, 0.0, 1.0]]))
        (root / "big.yaml").write_text("%YAML:1.0\n---\nimage_width: 640\nimage_height: 480\ncamera_matrix: !!opencv-matrix\n"
                                       "   rows: 100000\n   cols: 100000\n   dt: d\n   data: [ 1. ]\n"
                                       "distortion_coefficients: !!opencv-matrix\n   rows: 1\n   cols: 5\n   dt: d\n"
                                       "   data: [ 0., 0., 0., 0., 0. ]\n")
        (root / "one").mkdir()
        (root / "one" / "a.png").write_bytes(png_declaring(64, 64))
        cases = [
            ("calibrate board, PNG declaring 200000^2", ["calibrate", "board", "--board", "chessboard:9x6:0.025",
                                                        "--images", "c=png/*.png", "--out", "out1/r.rig.json"]),
            ("calibrate board, JPEG declaring 65500^2", ["calibrate", "board", "--board", "chessboard:9x6:0.025",
                                                        "--images", "c=jpg/*.jpg", "--out", "out2/r.rig.json"]),
            ("rig show, 100000 arrays deep", ["rig", "show", "deep.rig.json"]),
            ("stmap, a 10^9 x 10^9 image", ["stmap", "huge.rig.json", "--camera", "cam", "--out", "out3"]),
            ("stmap, fx = 1e308", ["stmap", "fx.rig.json", "--camera", "cam", "--out", "out4"]),
            ("rig import, 100000^2 camera_matrix", ["rig", "import", "big.yaml", "--from", "opencv",
                                                   "--out", "out5/a.rig.json"]),
            ("solve, one image", ["solve", "one", "--out", "out6"]),
        ]
        worst = 0.0
        for label, argv in cases:
            before = sorted(p.name for p in root.iterdir())
            code, line, peak_mb = peak_run(argv, root)
            left = sorted(set(p.name for p in root.iterdir()) - set(before))
            worst = max(worst, peak_mb)
            print(f"{label}: exit {code}, peak {peak_mb:.0f} MB, left behind {left or 'nothing'}\n    {line}")
        print(f"hostile files: worst peak memory {worst:.0f} MB (bound {BOUND_MB:.0f} MB), "
              f"ratio bound/worst {BOUND_MB / worst:.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
