"""The caps of camcal.base.limits and the JSON reader's: file size, nesting depth, non-finite numbers."""

import json

import pytest

from camcal.base.errors import CamcalError
from camcal.base.jsonfile import parse_json, read_json
from camcal.base.limits import IMAGE_PIXELS, JSON_DEPTH, check_image_size


def one_line(error: pytest.ExceptionInfo) -> str:
    message = str(error.value)
    assert "\n" not in message and "Traceback" not in message
    return message


def test_a_cap_is_its_default_unless_the_environment_says(monkeypatch):
    monkeypatch.delenv("CAMCAL_MAX_IMAGE_PIXELS", raising=False)
    assert IMAGE_PIXELS.value == 2**28
    monkeypatch.setenv("CAMCAL_MAX_IMAGE_PIXELS", "1_073_741_824")
    assert IMAGE_PIXELS.value == 2**30


@pytest.mark.parametrize("text", ["lots", "-5", "0", "1.5"])
def test_a_cap_set_to_nonsense_is_refused(monkeypatch, text):
    monkeypatch.setenv("CAMCAL_MAX_IMAGE_PIXELS", text)
    with pytest.raises(CamcalError, match="CAMCAL_MAX_IMAGE_PIXELS must be a positive integer") as error:
        check_image_size(10, 10, "image")
    one_line(error)


def test_the_pixel_cap_names_the_size_the_cap_and_how_to_raise_it(monkeypatch):
    monkeypatch.delenv("CAMCAL_MAX_IMAGE_PIXELS", raising=False)
    check_image_size(16384, 16384, "image")  # a 16K square plate is within the default
    with pytest.raises(CamcalError) as error:
        check_image_size(200_000, 200_000, "x.png: the header declares")
    message = one_line(error)
    assert message.startswith("x.png: the header declares 200000x200000 pixels")
    assert "268,435,456" in message and "CAMCAL_MAX_IMAGE_PIXELS" in message
    monkeypatch.setenv("CAMCAL_MAX_IMAGE_PIXELS", str(200_000 * 200_000))
    check_image_size(200_000, 200_000, "image")


def test_json_nested_100000_deep_is_one_line_naming_the_file(tmp_path):
    path = tmp_path / "deep.rig.json"
    path.write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(CamcalError) as error:
        read_json(path, "rig file")
    message = one_line(error)
    assert message.startswith(f"{path}: ") and "nested deeper than 64 levels" in message
    assert "CAMCAL_MAX_JSON_DEPTH" in message


def test_json_nesting_is_capped_below_what_the_parser_survives():
    parse_json("[" * JSON_DEPTH.default + "]" * JSON_DEPTH.default)
    with pytest.raises(CamcalError, match=r"\[0\]\[0\].*nested deeper than 64 levels"):
        parse_json('{"a": ' + "[" * JSON_DEPTH.default + "]" * JSON_DEPTH.default + "}")


@pytest.mark.parametrize("literal, found", [("NaN", "non-finite number NaN"), ("-Infinity", "non-finite number -Infinity"),
                                            ("1e999", "number out of range")])
def test_non_finite_numbers_are_refused_with_their_field(tmp_path, literal, found):
    path = tmp_path / "a.rig.json"
    path.write_text('{"cameras": [{"K": [[1, 0, 2], [0, ' + literal + ', 3]]}]}')
    with pytest.raises(CamcalError) as error:
        read_json(path, "rig file")
    assert one_line(error) == f"{path}: cameras[0].K[1][1]: {found}" + (
        " (read as inf) in JSON" if literal == "1e999" else " in JSON")


def test_an_integer_too_long_to_convert_is_bad_input(tmp_path):
    path = tmp_path / "a.json"
    path.write_text(json.dumps({"n": 0})[:-2] + "9" * 5000 + "}")
    with pytest.raises(CamcalError, match="not valid JSON") as error:
        read_json(path)
    one_line(error)


def test_a_json_file_past_the_size_cap_is_not_read(tmp_path, monkeypatch):
    path = tmp_path / "big.json"
    path.write_text(json.dumps({"pad": "x" * 2000}))
    monkeypatch.setenv("CAMCAL_MAX_JSON_BYTES", "1000")
    with pytest.raises(CamcalError) as error:
        read_json(path, "rig file")
    message = one_line(error)
    assert message.startswith(f"{path}: rig file of 2,") and "over the cap of 1,000" in message
    assert "CAMCAL_MAX_JSON_BYTES" in message
    monkeypatch.delenv("CAMCAL_MAX_JSON_BYTES")
    assert read_json(path)["pad"] == "x" * 2000
