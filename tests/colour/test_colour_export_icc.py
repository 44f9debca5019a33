"""ICC camera profiles: structure against the ICC.1 rules, LittleCMS (and ArgyllCMS) as peers."""

import hashlib
import os
import shutil
import struct
import subprocess

import numpy as np
import pytest

from camcal.colour.evaluate import delta_E
from camcal.colour.export_icc import D50_XYZ, check_icc, export_icc, icc_profile_from_fit, write_icc
from camcal.colour.lcms import lcms_to_XYZ, load_lcms
from camcal.base.errors import CamcalError
from colour_export_helpers import code_grid, codes_of, make_fit

CASES = [("matrix3x3", "gamma-offset", 4), ("matrix3x3", "gamma-offset", 2), ("matrix3x3", "lut1d", 4),
         ("root-polynomial:2", "gamma-offset", 4), ("root-polynomial:2", "lut1d", 2),
         ("polynomial:10", "gamma-offset", 2)]


@pytest.fixture(scope="module")
def profiles(sim):
    out = {}
    for model, lin, version in CASES:
        fit = make_fit(sim, model, linearise=lin)
        out[(model, lin, version)] = (fit, icc_profile_from_fit(fit, "nikon", version=version))
    return out


def _truth_D50(fit, codes):
    import colour

    return colour.chromatic_adaptation(fit.apply_codes(codes), np.asarray(fit.target_white_XYZ),
                                       np.asarray(D50_XYZ), method="Von Kries", transform="Bradford")


@pytest.mark.parametrize("case", CASES, ids=lambda c: "-".join(map(str, c)))
def test_structure_follows_icc1(profiles, case):
    fit, profile = profiles[case]
    data = profile.data
    info = check_icc(data)
    size, = struct.unpack(">I", data[:4])
    assert size == len(data) and size % 4 == 0
    assert (info.device_class, info.colour_space, info.pcs) == ("scnr", "RGB ", "XYZ ")
    assert info.version_major == case[2]
    for offset, length, _ in info.tags.values():
        assert offset % 4 == 0 and offset + length <= size
    assert {"desc", "cprt", "wtpt", "chad"} <= set(info.tags)
    if case[0] == "matrix3x3":
        assert {"rXYZ", "gXYZ", "bXYZ", "rTRC", "gTRC", "bTRC"} <= set(info.tags)
    else:
        assert info.tags["A2B0"][2] == ("mAB " if case[2] == 4 else "mft2")
    zeroed = bytearray(data)
    zeroed[44:48] = zeroed[64:68] = b"\0" * 4
    zeroed[84:100] = b"\0" * 16
    expected_id = hashlib.md5(bytes(zeroed)).digest() if case[2] == 4 else b"\0" * 16
    assert data[84:100] == expected_id


@pytest.mark.parametrize("case", CASES, ids=lambda c: "-".join(map(str, c)))
def test_littlecms_reproduces_the_fit(profiles, case, sim):
    lib = load_lcms()
    if lib is None:
        if os.environ.get("CAMCAL_REQUIRE_ICC_TOOLS"):
            pytest.fail("CAMCAL_REQUIRE_ICC_TOOLS is set but LittleCMS (liblcms2) is not available")
        pytest.skip("LittleCMS (liblcms2, or Pillow's bundled copy) is not available")
    fit, profile = profiles[case]
    from scipy.spatial import Delaunay

    from camcal.colour.export_ocio import chart_gamut_samples

    grid = code_grid(25)
    grid = grid[Delaunay(chart_gamut_samples(fit)).find_simplex(fit.linearise(grid)) >= 0]
    assert len(grid) > 200
    for codes in (codes_of(sim.RGB_train), codes_of(sim.RGB_test), grid):
        got = lcms_to_XYZ(lib, profile.data, codes)
        truth = _truth_D50(fit, codes)
        keep = truth[:, 1] > 0.01  # CIEDE2000 near black, or of impossible (negative) XYZ, says nothing
        dE = delta_E(got[keep], truth[keep], D50_XYZ)
        assert dE.max() < 0.5, (case, dE.max())


def test_pillow_reads_every_profile(profiles, sim):
    ImageCms = pytest.importorskip("PIL.ImageCms")
    from io import BytesIO

    from PIL import Image

    lab_profile = ImageCms.createProfile("LAB", 5000)
    codes8 = np.round(codes_of(sim.RGB_train) * 255).astype(np.uint8)
    for (model, lin, version), (fit, profile) in profiles.items():
        opened = ImageCms.ImageCmsProfile(BytesIO(profile.data))
        assert opened.profile.device_class == "scnr" and opened.profile.xcolor_space == "RGB "
        assert opened.profile.connection_space == "XYZ " and int(opened.profile.version) == version
        transform = ImageCms.buildTransform(opened, lab_profile, "RGB", "LAB",
                                            ImageCms.Intent.RELATIVE_COLORIMETRIC)
        image = Image.fromarray(codes8[None], "RGB")
        lab = np.asarray(ImageCms.applyTransform(image, transform), dtype=np.float64)[0]
        import colour

        expected = colour.XYZ_to_Lab(_truth_D50(fit, codes8 / 255.0), colour.XYZ_to_xy(D50_XYZ))
        got = np.column_stack([lab[:, 0] * 100 / 255, lab[:, 1] - 128 * (lab[:, 1] > 127) * 2 + 0, lab[:, 2]])
        got[:, 1:] = np.where(lab[:, 1:] > 127, lab[:, 1:] - 256, lab[:, 1:])
        # 8-bit Lab: L* steps of 100/255, a*, b* steps of 1: half a step of rounding plus the bake
        assert np.abs(got[:, 0] - expected[:, 0]).max() < 0.2 + 0.5, (model, version)
        assert np.abs(got[:, 1:] - expected[:, 1:]).max() < 0.5 + 0.5, (model, version)


def test_corrupt_or_truncated_profiles_are_refused(profiles, tmp_path):
    fit, profile = profiles[("root-polynomial:2", "gamma-offset", 4)]
    data = profile.data
    with pytest.raises(CamcalError, match="size field"):
        check_icc(data[:-4])
    flipped = bytearray(data)
    flipped[-1] ^= 0xFF
    with pytest.raises(CamcalError, match="profile ID"):
        check_icc(bytes(flipped))
    moved = bytearray(data)
    moved[132 + 4:132 + 8] = struct.pack(">I", struct.unpack(">I", data[136:140])[0] + 2)
    with pytest.raises(CamcalError, match="out of bounds or unaligned"):
        check_icc(bytes(moved))
    target = tmp_path / "bad.icc"
    with pytest.raises(CamcalError):
        write_icc(type(profile)(data[:-4], 4, "lut"), target)
    assert not target.exists() and not list(tmp_path.iterdir())
    with pytest.raises(CamcalError, match=r"5\^3 (CLUT|Lut3D) still leaves"):
        export_icc(fit, "nikon", target, lut_sizes=(5,))
    assert not target.exists()
    assert export_icc(fit, "nikon", target).data == target.read_bytes()


def _ti3(path, codes, XYZ):
    lines = ["CTI3", 'DESCRIPTOR "camcal test"', 'ORIGINATOR "camcal"', 'DEVICE_CLASS "INPUT"',
             'COLOR_REP "XYZ_RGB"', "", "NUMBER_OF_FIELDS 7", "BEGIN_DATA_FORMAT",
             "SAMPLE_ID RGB_R RGB_G RGB_B XYZ_X XYZ_Y XYZ_Z", "END_DATA_FORMAT", "",
             f"NUMBER_OF_SETS {len(codes)}", "BEGIN_DATA"]
    for i, (c, X) in enumerate(zip(codes * 100, XYZ * 100), start=1):
        lines.append(f"{i} {c[0]:.6f} {c[1]:.6f} {c[2]:.6f} {X[0]:.6f} {X[1]:.6f} {X[2]:.6f}")
    path.write_text("\n".join(lines + ["END_DATA", ""]))


def test_argyll_reads_v2_profiles(profiles, tmp_path, sim):
    """ArgyllCMS (Debian's build reads ICC v2 only): iccdump -v 3 and profcheck's CIEDE2000."""
    if not (shutil.which("iccdump") and shutil.which("profcheck")):
        if os.environ.get("CAMCAL_REQUIRE_ICC_TOOLS"):
            pytest.fail("CAMCAL_REQUIRE_ICC_TOOLS is set but ArgyllCMS (iccdump, profcheck) is not installed")
        pytest.skip("ArgyllCMS (iccdump, profcheck) is not installed")
    for (model, lin, version), (fit, profile) in profiles.items():
        if version != 2:
            continue
        path = tmp_path / f"{model}-{lin}.icc"
        path.write_bytes(profile.data)
        dump = subprocess.run(["iccdump", "-v", "3", str(path)], capture_output=True, text=True)
        assert dump.returncode == 0 and "Error" not in dump.stdout + dump.stderr
        assert "Device Class = Input" in dump.stdout
        codes = codes_of(sim.RGB_train)
        ti3 = tmp_path / f"{model}-{lin}.ti3"
        _ti3(ti3, codes, _truth_D50(fit, codes))
        check = subprocess.run(["profcheck", "-k", str(ti3), str(path)], capture_output=True, text=True)
        assert check.returncode == 0, check.stderr
        line = [s for s in check.stdout.splitlines() if "max." in s][-1]
        assert float(line.split("max. =")[1].split(",")[0]) < 0.5, line
