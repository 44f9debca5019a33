"""Native output (file descriptors 1 and 2) captured into a log file; Python's own lines still shown."""

import subprocess
import sys
import textwrap


def _run(tmp_path, echo: bool) -> subprocess.CompletedProcess:
    script = textwrap.dedent(f"""
        import os, sys
        from camcal.base.native_log import native_output_to
        with native_output_to({str(tmp_path / "out" / "native.log")!r}, echo={echo}):
            os.write(2, b"I20261125 21:37:31.424757 1 native.cc:1] from C on fd 2\\n")
            os.write(1, b"from C on fd 1\\n")
            print("camcal: a line of our own", file=sys.stderr)
            print("camcal: on stdout")
        os.write(2, b"after the block\\n")
        try:
            with native_output_to({str(tmp_path / "out" / "native.log")!r}):
                os.write(2, b"W20261125 before an error\\n")
                raise RuntimeError("boom")
        except RuntimeError:
            print("caught", file=sys.stderr)
    """)
    return subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)


def test_native_lines_go_to_the_log_only(tmp_path):
    run = _run(tmp_path, echo=False)
    log = (tmp_path / "out" / "native.log").read_text()
    assert "from C on fd 2" in log and "from C on fd 1" in log and "before an error" in log
    assert "camcal" not in log and "after the block" not in log
    assert run.stderr.splitlines() == ["camcal: a line of our own", "after the block", "caught"]
    assert run.stdout.splitlines() == ["camcal: on stdout"]


def test_echo_copies_native_lines_to_stderr(tmp_path):
    run = _run(tmp_path, echo=True)
    assert "from C on fd 2" in run.stderr and "from C on fd 1" in run.stderr
    assert "camcal: a line of our own" in run.stderr and "from C" not in run.stdout


def test_opencv_log_level_is_set_through_either_opencv_api():
    """OpenCV 5's cv2.utils.logging, or OpenCV 4's cv2.setLogLevel: the level set, the previous one returned."""
    from types import SimpleNamespace

    import cv2

    from camcal.base.native_log import OPENCV_LOG_ERROR, OPENCV_LOG_SILENT, set_opencv_log_level

    before = set_opencv_log_level(cv2, OPENCV_LOG_SILENT)
    try:
        assert set_opencv_log_level(cv2, OPENCV_LOG_ERROR) == OPENCV_LOG_SILENT
    finally:
        assert set_opencv_log_level(cv2, before) == OPENCV_LOG_ERROR

    levels = [3]  # OpenCV 4's shape: no cv2.utils.logging, the setter at the top
    opencv4 = SimpleNamespace(utils=SimpleNamespace(), getLogLevel=lambda: levels[-1], setLogLevel=levels.append)
    assert set_opencv_log_level(opencv4, OPENCV_LOG_ERROR) == 3 and levels == [3, 2]


def test_glog_level_drops_ceres_warnings_for_the_block_only():
    """pyceres' own glog (Ceres' "Linear solver failure" warnings in a bundle adjustment): silent inside the block,
    as before after it, the previous level restored."""
    script = textwrap.dedent("""
        import pyceres
        from camcal.base.native_log import glog_level
        with glog_level(pyceres):
            pyceres.logging.warning("inside the block")
        pyceres.logging.warning("after the block")
        print(pyceres.logging.minloglevel)
    """)
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, check=True)
    assert "inside the block" not in run.stderr and "after the block" in run.stderr
    assert run.stdout.strip() == "0"



def test_a_process_started_in_the_block_that_outlives_it_does_not_hold_the_block_open(tmp_path):
    """A child inherits the capture pipe as its fds 1 / 2 (a Dask worker a nanny restarts inside the block) and is
    still running when the block ends: the block ends anyway, with the child's earlier line in the log, and what the
    child writes afterwards is neither in the log nor on the terminal."""
    script = textwrap.dedent(f"""
        import os, pathlib, subprocess, sys, threading
        from camcal.base.native_log import native_output_to
        log = {str(tmp_path / "native.log")!r}
        child_code = "import os, sys; os.write(2, b'child before\\\\n'); sys.stdin.read(); os.write(2, b'child after\\\\n')"
        ended = threading.Event()

        def block():
            with native_output_to(log):
                child = subprocess.Popen([sys.executable, "-c", child_code], stdin=subprocess.PIPE)
                os.write(2, b"parent in the block\\n")
                while "child before" not in pathlib.Path(log).read_text():
                    pass
            block.child = child
            ended.set()

        worker = threading.Thread(target=block, daemon=True)
        worker.start()
        worker.join(120)
        print("ended" if ended.is_set() else "held open")
        child = block.child
        print("child running" if child.poll() is None else "child gone")
        child.stdin.close()
        child.wait()
    """)
    run = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300)
    assert run.stdout.splitlines() == ["ended", "child running"], run.stdout + run.stderr
    log = (tmp_path / "native.log").read_text()
    assert "parent in the block" in log and "child before" in log
    assert "child after" not in log and "child after" not in run.stderr
