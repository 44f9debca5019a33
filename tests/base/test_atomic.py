"""Atomic outputs get the permissions of an ordinary file (umask), not mkstemp's 0600."""

import os
import stat

from camcal.base.atomic import atomic_write_text


def test_atomic_output_has_umask_permissions(tmp_path):
    reference = tmp_path / "plain.txt"
    reference.write_text("x")
    atomic_write_text(tmp_path / "atomic.txt", "x")
    mode = stat.S_IMODE(os.stat(tmp_path / "atomic.txt").st_mode)
    assert mode == stat.S_IMODE(os.stat(reference).st_mode)
    assert mode & stat.S_IRGRP  # readable by the group under the usual umask 022 / 002


# -- atomic_dir ------------------------------------------------------------------


from pathlib import Path  # noqa: E402

import pytest  # noqa: E402

from camcal.base.atomic import atomic_dir, final_path  # noqa: E402
from camcal.base.errors import CamcalError  # noqa: E402


def _listing(root: Path) -> list[str]:
    return sorted(str(p.relative_to(root)) for p in root.rglob("*"))


def test_atomic_dir_renames_a_new_folder(tmp_path):
    target = tmp_path / "a" / "b" / "out"
    with atomic_dir(target) as staging:
        assert staging.parent == target.parent and staging.name.startswith(".out.")
        (staging / "sub").mkdir()
        (staging / "sub" / "x.txt").write_text("x")
        assert not target.exists()  # nothing visible under the final name before the end
        assert final_path(staging / "sub" / "x.txt", staging, target) == target / "sub" / "x.txt"
    assert _listing(tmp_path) == ["a", "a/b", "a/b/out", "a/b/out/sub", "a/b/out/sub/x.txt"]
    mode = os.stat(target).st_mode & 0o777
    reference = tmp_path / "plain"
    reference.mkdir()
    assert mode == os.stat(reference).st_mode & 0o777


@pytest.mark.parametrize("error", [CamcalError("bad input"), RuntimeError("a bug"), KeyboardInterrupt()])
def test_atomic_dir_leaves_nothing_behind(tmp_path, error):
    (tmp_path / "keep.txt").write_text("k")
    before = _listing(tmp_path)
    with pytest.raises(type(error)):
        with atomic_dir(tmp_path / "new" / "deeper" / "out") as staging:
            (staging / "half.txt").write_text("half")
            raise error
    assert _listing(tmp_path) == before  # the staging folder and the parents it created are gone


def test_atomic_dir_into_an_existing_folder(tmp_path):
    target = tmp_path / "out"
    (target / "left").mkdir(parents=True)
    (target / "mine.txt").write_text("the user's")
    (target / "left" / "a.png").write_text("old")
    with pytest.raises(CamcalError):
        with atomic_dir(target) as staging:
            (staging / "left").mkdir()
            (staging / "left" / "a.png").write_text("half")
            raise CamcalError("bad input")
    assert (target / "left" / "a.png").read_text() == "old"
    assert _listing(tmp_path) == ["out", "out/left", "out/left/a.png", "out/mine.txt"]
    with atomic_dir(target) as staging:
        (staging / "left").mkdir()
        (staging / "left" / "a.png").write_text("new")
        (staging / "left" / "b.png").write_text("new")
    assert (target / "left" / "a.png").read_text() == "new" and (target / "mine.txt").read_text() == "the user's"
    assert _listing(tmp_path) == ["out", "out/left", "out/left/a.png", "out/left/b.png", "out/mine.txt"]


def test_atomic_dir_refuses_a_file(tmp_path):
    (tmp_path / "out").write_text("a file")
    with pytest.raises(CamcalError, match="not a folder"):
        with atomic_dir(tmp_path / "out"):
            pass


# -- temporary names and stale temporaries ------------------------------------------------


from camcal.base.atomic import (  # noqa: E402
    TEMPORARY_TAG, atomic_path, is_temporary_of, remove_stale_temporaries,
)


def test_temporaries_carry_camcal_tag_and_are_recognised(tmp_path):
    target = tmp_path / "o.0032.png"
    with atomic_path(target) as tmp:
        assert f".{TEMPORARY_TAG}." in tmp.name and tmp.suffix == ".png" and is_temporary_of(tmp, target)
        assert not is_temporary_of(tmp, tmp_path / "o.0033.png")
        assert not is_temporary_of(tmp_path / "sub" / tmp.name, target)
    with atomic_dir(tmp_path / "solved") as staging:
        assert is_temporary_of(staging, tmp_path / "solved")


def test_remove_stale_temporaries_touches_only_the_targets_own(tmp_path):
    targets = [tmp_path / "o.0032.png", tmp_path / "solved"]
    stale = [tmp_path / f".o.0032.png.{TEMPORARY_TAG}.0jfiou1u.png", tmp_path / f".solved.{TEMPORARY_TAG}.a_b9z0x1"]
    kept = [tmp_path / "o.0032.png", tmp_path / ".o.0032.png.0jfiou1u.png", tmp_path / f".o.0033.png.{TEMPORARY_TAG}.0jfiou1u.png",
            tmp_path / f".o.0032.png.{TEMPORARY_TAG}.short.png", tmp_path / "notes.txt"]
    stale[0].write_bytes(b"half")
    stale[1].mkdir()
    (stale[1] / "database.db").write_bytes(b"x")
    for path in kept:
        path.write_bytes(b"k")
    assert remove_stale_temporaries(targets + [tmp_path / "missing" / "x.png"]) == tuple(sorted(stale))
    assert sorted(tmp_path.iterdir()) == sorted(kept)
