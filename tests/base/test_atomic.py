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
