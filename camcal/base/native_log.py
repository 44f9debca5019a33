"""Output that native libraries write straight to file descriptors 1 and 2, captured into a log file.

COLMAP, glog and Ceres (inside pycolmap and pyceres) print their progress
lines (``I20261125 21:37:31.42 ... feature_extraction.cc:498] ...``) and
warnings (``Linear solver failure``) with ``fwrite`` on the process's
standard error, not through Python's ``sys.stderr``: redirecting
``sys.stderr`` does not silence them. :func:`native_output_to` redirects
the descriptors themselves (``os.dup2`` onto a pipe) for the duration of a
``with`` block; a thread copies what arrives into the log file and, when
asked, on to the real stderr. The block's end is an end marker written
into the pipe, not the pipe's end of file: a process started inside the
block (a Dask worker restarted by a nanny, a child of a native library)
inherits the pipe as its descriptors 1 / 2 and may outlive the block, and
waiting for its end of file would wait for it. Python's own ``sys.stdout`` / ``sys.stderr``
are pointed at the real descriptors meanwhile, so the caller's lines
(progress, messages) still reach the terminal and stay out of the log.

OpenCV's own log lines are not captured but turned down, with
:func:`set_opencv_log_level`.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import sys
import threading
import uuid
from collections.abc import Iterator
from pathlib import Path
from types import ModuleType

__all__ = ["GLOG_ERROR", "OPENCV_LOG_ERROR", "OPENCV_LOG_SILENT", "glog_level", "native_output_to", "set_opencv_log_level"]

_CHUNK = 65536


def _flush_c_stdio() -> None:
    """Flush the C library's stdio buffers (``fflush(NULL)``), where a libc is loadable."""
    try:
        ctypes.CDLL(None).fflush(None)
    except (OSError, AttributeError):
        pass


def _python_stream_on(fd: int):
    """``sys.stdout`` or ``sys.stderr`` if it writes to descriptor ``fd`` (not when a test harness replaced it)."""
    stream = sys.stdout if fd == 1 else sys.stderr
    try:
        return stream if stream is not None and stream.fileno() == fd else None
    except (AttributeError, OSError, ValueError):
        return None


@contextlib.contextmanager
def native_output_to(log_path: str | os.PathLike, echo: bool = False, fds: tuple[int, ...] = (1, 2)) -> Iterator[Path]:
    """Send what native code writes to ``fds`` into ``log_path`` (appended) while the block runs.

    Parameters
    ----------
    log_path : path
        The log file; created (with its folder) or appended to.
    echo : bool
        Also copy every captured line to the real standard error
        (``--verbose``).
    fds : tuple of int
        The descriptors captured (1 stdout, 2 stderr).

    Yields
    ------
    Path
        The log file.

    Notes
    -----
    The descriptors are restored in a ``finally``, after the C library's
    buffers are flushed and the copying thread has drained the pipe, so an
    exception inside the block leaves the process's output as it was.
    """
    log_path = Path(log_path)
    log_path.parent.mkdir(parents=True, exist_ok=True)
    for stream in (sys.stdout, sys.stderr):
        with contextlib.suppress(AttributeError, OSError, ValueError):
            stream.flush()
    _flush_c_stdio()
    saved = {fd: os.dup(fd) for fd in fds}
    read_end, write_end = os.pipe()
    log = open(log_path, "ab")  # noqa: SIM115 - closed in the finally below
    echo_fd = saved.get(2, 2)

    # written once, atomically (shorter than PIPE_BUF), after the block's own output: the copier stops there
    end_marker = b"\0camcal-native-log-end:" + uuid.uuid4().hex.encode() + b"\0"

    def emit(data: bytes) -> None:
        if not data:
            return
        log.write(data)
        log.flush()
        if echo:
            with contextlib.suppress(OSError):
                os.write(echo_fd, data)

    def copy() -> None:
        pending = b""
        while True:
            chunk = os.read(read_end, _CHUNK)
            if not chunk:
                emit(pending)
                return
            pending += chunk
            at = pending.find(end_marker)
            if at >= 0:
                emit(pending[:at])
                return
            held = _marker_prefix_length(pending, end_marker)
            emit(pending[:len(pending) - held])
            pending = pending[len(pending) - held:]

    copier = threading.Thread(target=copy, name="native-output-log", daemon=True)
    copier.start()
    swapped = {}
    try:
        for fd in fds:
            os.dup2(write_end, fd)
        # the caller's own Python lines go to the real descriptors, not into the log
        for fd in fds:
            stream = _python_stream_on(fd)
            if stream is not None:
                # its own descriptor, closed when the last reference goes (a progress bar may keep one)
                replacement = open(os.dup(saved[fd]), "w", encoding=getattr(stream, "encoding", None) or "utf-8",  # noqa: SIM115
                                   errors="backslashreplace", buffering=1)
                swapped[fd] = (stream, replacement)
                if fd == 1:
                    sys.stdout = replacement
                else:
                    sys.stderr = replacement
        yield log_path
    finally:
        for fd, (stream, replacement) in swapped.items():
            replacement.flush()
            if fd == 1:
                sys.stdout = stream
            else:
                sys.stderr = stream
        _flush_c_stdio()
        for fd in fds:
            os.dup2(saved[fd], fd)
        os.write(write_end, end_marker)  # after everything the block wrote: the copier stops there
        os.close(write_end)
        copier.join()
        for fd in fds:
            os.close(saved[fd])
        os.close(read_end)  # a process that outlives the block now gets EPIPE instead of filling the pipe
        log.close()


def _marker_prefix_length(data: bytes, marker: bytes) -> int:
    """The length of the longest end of ``data`` that begins ``marker`` (bytes held back until the next read)."""
    for length in range(min(len(marker) - 1, len(data)), 0, -1):
        if data.endswith(marker[:length]):
            return length
    return 0


#: glog's severity of errors (``google::GLOG_ERROR``): a ``minloglevel`` of 2 drops INFO and WARNING lines
GLOG_ERROR = 2


@contextlib.contextmanager
def glog_level(module: ModuleType, level: int = GLOG_ERROR) -> Iterator[None]:
    """Raise the glog ``minloglevel`` of a native module (``pyceres``, ``pycolmap``) while the block runs.

    Each wheel links its own glog: Ceres inside ``pyceres.solve`` warns
    through pyceres' copy (``W... levenberg_marquardt_strategy.cc:123]
    Linear solver failure``: a rejected Levenberg-Marquardt step, which the
    solver handles by raising its damping), which ``pycolmap.logging`` does
    not reach. glog reads the flag at every log call, so the level holds
    exactly for the block; the previous level is restored after it.
    """
    logging = module.logging
    previous = logging.minloglevel
    logging.minloglevel = max(int(previous), int(level))
    try:
        yield
    finally:
        logging.minloglevel = previous


#: OpenCV's log levels (``cv::utils::logging::LogLevel``), the same numbers in OpenCV 4 and 5
OPENCV_LOG_SILENT, OPENCV_LOG_ERROR = 0, 2


def set_opencv_log_level(cv2: ModuleType, level: int) -> int:
    """Set OpenCV's log level; returns the level it had.

    OpenCV 5 keeps the setter in ``cv2.utils.logging``; OpenCV 4 has it as
    ``cv2.setLogLevel`` / ``cv2.getLogLevel``. The levels are the same
    numbers in both (:data:`OPENCV_LOG_SILENT`, :data:`OPENCV_LOG_ERROR`).

    Parameters
    ----------
    cv2
        The imported ``cv2`` module (passed in: this module does not import OpenCV).
    level
        The new level.
    """
    logging = getattr(cv2.utils, "logging", None)
    api = logging if hasattr(logging, "setLogLevel") else cv2
    previous = int(api.getLogLevel())
    api.setLogLevel(level)
    return previous
