"""``camcal solve`` on a Movie Clip, run in a subprocess: the command, its progress, cancel (no bpy).

The add-on never imports camcal (Blender's Python need not have it, and
camcal's numerical stack does not belong inside Blender): it runs the
``camcal`` executable (found on the PATH, or the path set in the add-on's
preferences) with ``subprocess.Popen`` and no shell, and reads what camcal
prints. ``camcal solve --json`` prints its stage lines on stderr
(``camcal solve: matching (sequential)``) and, at the end, one JSON object on
stdout whose ``files`` name the rig it wrote (kind ``rig``) and whose
``figures`` hold the registered count and the RMS; on an error the last
stderr line is ``camcal: error: <one line>``.

camcal writes its output folder atomically: the run builds
``.OUT.camcal-tmp.XXXXXXXX`` beside ``OUT`` and renames it at the end; an
interrupted run (SIGINT) removes it itself. :meth:`SolveJob.cancel` sends
SIGINT to the run's process group, waits ``grace_s``, kills what is left
(SIGKILL: no cleanup runs then) and removes every entry that appeared beside
``OUT`` during the run and is named after it (``.OUT.*``), the output folder
itself if the run created it, and the folder above it if the job created it
and it is empty: nothing of a cancelled run is left, nor of a failed one.
"""

from __future__ import annotations

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from dataclasses import dataclass

__all__ = [
    "SolveError",
    "ClipSource",
    "STAGES",
    "find_camcal",
    "sequence_pattern",
    "camera_name",
    "solve_command",
    "stage_fraction",
    "SolveJob",
]

#: camcal solve's stage lines, in the order it prints them (``camcal solve: <stage>...``): the progress fraction.
STAGES = ("extracting features", "matching", "mapping", "bundle adjustment", "lens model", "uncertainty")
_PREFIX = "camcal solve: "
_DIGITS = re.compile(r"(\d+)(?=\D*$)")


class SolveError(Exception):
    """A solve that cannot start or that failed: one line naming the problem."""


@dataclass(frozen=True)
class ClipSource:
    """What camcal reads of a Movie Clip.

    ``path`` is the movie file, or the clip's first image of a sequence;
    ``first`` the file number of the clip's first frame (sequences; 0 for a
    movie) and ``n_frames`` its length; ``name`` the camera's name in the rig.
    """

    path: str
    kind: str  # "SEQUENCE" or "MOVIE"
    first: int
    n_frames: int
    name: str


def find_camcal(configured: str = "") -> str:
    """The camcal executable: ``configured`` (the add-on preferences) if set, else ``camcal`` on the PATH.

    Raises
    ------
    SolveError
        The configured file is not an executable, or camcal is not on the PATH.
    """
    if configured:
        path = os.path.abspath(os.path.expanduser(configured))
        if not (os.path.isfile(path) and os.access(path, os.X_OK)):
            raise SolveError(f"camcal executable not found or not executable: {path} (the add-on's preferences)")
        return path
    found = shutil.which("camcal")
    if found is None:
        raise SolveError("camcal was not found on the PATH: install it (pip install camcal) "
                         "or set its path in the add-on's preferences")
    return found


def sequence_pattern(path: str) -> tuple[str, int]:
    """The printf pattern of an image sequence from one of its files, and that file's number.

    The last run of digits in the file name is the frame number:
    ``plate.1001.exr`` -> ``("plate.%04d.exr", 1001)`` (camcal's plate notation).

    Raises
    ------
    SolveError
        The file name has no frame number.
    """
    name = os.path.basename(path)
    match = _DIGITS.search(name)
    if match is None:
        raise SolveError(f"the image sequence {path} has no frame number in its file name")
    digits = match.group(1)
    if "%" in name or "#" in name:
        raise SolveError(f"the image sequence {path}: '%' or '#' in its file name cannot be passed to camcal")
    return name[:match.start()] + f"%0{len(digits)}d" + name[match.end():], int(digits)


def camera_name(clip_name: str) -> str:
    """A camera name for the rig from a clip's name: its stem, letters, digits, ``_`` and ``-`` only."""
    stem = clip_name.split(".")[0] if not clip_name.startswith(".") else clip_name
    cleaned = re.sub(r"[^A-Za-z0-9_-]+", "_", stem).strip("_")
    return cleaned or "plate"


def solve_command(executable: str, source: ClipSource, out: str, *, features: int = 8192,
                  matcher: str = "sequential", model: str = "auto") -> list[str]:
    """The ``camcal solve`` command line for a clip (an argument list: no shell).

    A sequence is ``--images NAME=PATTERN --frames FIRST-LAST`` (every frame of
    the clip must exist); a movie is ``--images NAME=MOVIE`` (every frame).
    ``--json`` makes camcal print its summary as one JSON object on stdout.
    """
    folder, name = os.path.split(os.path.abspath(source.path))
    command = [executable, "solve", folder]
    if source.kind == "SEQUENCE":
        pattern, _ = sequence_pattern(name)
        command += ["--images", f"{source.name}={pattern}",
                    "--frames", f"{source.first}-{source.first + source.n_frames - 1}"]
    elif source.kind == "MOVIE":
        command += ["--images", f"{source.name}={name}"]
    else:
        raise SolveError(f"clip {source.path}: unknown source {source.kind!r}, expected SEQUENCE or MOVIE")
    command += ["--features", str(int(features)), "--matcher", matcher, "--seed", "0", "--out", out, "--json"]
    if model != "auto":
        command += ["--model", model]
    return command


def stage_fraction(line: str, current: float = 0.0) -> float:
    """The share of the solve done when camcal prints ``line`` (:data:`STAGES`); other lines keep ``current``."""
    if line.startswith(_PREFIX):
        stage = line[len(_PREFIX):]
        for index, name in enumerate(STAGES):
            if stage.startswith(name):
                return max(current, index / len(STAGES))
    return current


class SolveJob:
    """One ``camcal solve`` run in a subprocess, polled without blocking.

    Parameters
    ----------
    command : list of str
        From :func:`solve_command`; its ``--out`` is ``out``.
    out : str
        The output folder camcal writes (atomically).
    grace_s : float
        Seconds :meth:`cancel` waits for camcal to clean up after SIGINT before it kills the run.
    """

    def __init__(self, command: list[str], out: str, grace_s: float = 5.0) -> None:
        self.command = list(command)
        self.out = os.path.abspath(out)
        self.grace_s = float(grace_s)
        self.process = None
        self.stderr_lines: list[str] = []
        self.stdout_text = ""
        self.fraction = 0.0
        self.returncode = None
        self._started = 0.0
        self._before: set[str] = set()
        self._made_parent = False
        self._out_existed = False
        self._readers: list[threading.Thread] = []
        self._lock = threading.Lock()

    # -- running -------------------------------------------------------------------------------------

    def start(self) -> None:
        """Start camcal (its own process group, so that cancel reaches everything it starts)."""
        parent = os.path.dirname(self.out)
        self._made_parent = not os.path.isdir(parent)
        try:
            os.makedirs(parent, exist_ok=True)
        except OSError as error:
            raise SolveError(f"cannot make the solve folder {parent}: {error.strerror or error} "
                             "(choose another output folder)") from None
        self._out_existed = os.path.exists(self.out)
        self._before = set(os.listdir(parent))
        group = ({"creationflags": subprocess.CREATE_NEW_PROCESS_GROUP} if sys.platform == "win32"
                 else {"start_new_session": True})
        try:
            self.process = subprocess.Popen(self.command, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                            stderr=subprocess.PIPE, text=True, encoding="utf-8",
                                            errors="replace", **group)
        except OSError as error:
            self._remove_leftovers()
            raise SolveError(f"cannot run {self.command[0]}: {error.strerror or error}") from None
        self._started = time.monotonic()
        self._readers = [threading.Thread(target=self._read_stderr, daemon=True),
                         threading.Thread(target=self._read_stdout, daemon=True)]
        for reader in self._readers:
            reader.start()

    def _read_stderr(self) -> None:
        for line in self.process.stderr:
            line = line.rstrip("\r\n")
            if line.strip():
                with self._lock:
                    self.stderr_lines.append(line)
                    self.fraction = stage_fraction(line, self.fraction)

    def _read_stdout(self) -> None:
        self.stdout_text = self.process.stdout.read()

    def poll(self) -> bool:
        """Whether the run has ended (its output read to the end; after a failure, nothing of it left)."""
        if self.process is None or self.process.poll() is None:
            return False
        if self.returncode is None:
            for reader in self._readers:
                reader.join()
            self.returncode = self.process.returncode
            if self.returncode != 0:
                self._remove_leftovers()
        return True

    def wait(self, interval_s: float = 0.1) -> None:
        """Block until the run ends."""
        while not self.poll():
            time.sleep(interval_s)

    @property
    def elapsed_s(self) -> float:
        """Seconds since the start."""
        return time.monotonic() - self._started if self._started else 0.0

    @property
    def last_line(self) -> str:
        """camcal's last line on stderr, without the ``camcal solve:`` prefix."""
        with self._lock:
            line = self.stderr_lines[-1] if self.stderr_lines else "starting"
        return line[len(_PREFIX):] if line.startswith(_PREFIX) else line.strip()

    def status_text(self) -> str:
        """``camcal solve 0:12 (40 %): matching (sequential) - Esc cancels`` for Blender's status bar."""
        seconds = int(self.elapsed_s)
        return (f"camcal solve {seconds // 60}:{seconds % 60:02d} ({round(100 * self.fraction)} %): "
                f"{self.last_line} - Esc cancels")

    # -- the end -------------------------------------------------------------------------------------

    def summary(self) -> dict:
        """camcal's JSON summary of a successful run.

        Raises
        ------
        SolveError
            The run failed (camcal's own error line) or printed no summary.
        """
        if self.returncode != 0:
            raise SolveError(self.error_line())
        try:
            return json.loads(self.stdout_text)
        except ValueError:
            raise SolveError(f"camcal solve printed no JSON summary (last line: {self.last_line})") from None

    def rig_path(self) -> str:
        """The rig file the run wrote (the summary's file of kind ``rig``)."""
        for entry in self.summary().get("files", []):
            if entry.get("kind") == "rig":
                return entry["path"]
        raise SolveError("camcal solve wrote no rig file")

    def error_line(self) -> str:
        """camcal's error line (``camcal: error: ...`` without the prefix), else its last line and exit code."""
        with self._lock:
            lines = list(self.stderr_lines)
        for line in reversed(lines):
            if line.startswith("camcal: error: "):
                return line[len("camcal: error: "):]
        last = lines[-1].strip() if lines else "no output"
        return f"camcal solve failed (exit code {self.returncode}): {last}"

    def cancel(self) -> None:
        """Stop the run and remove what it wrote: SIGINT, ``grace_s`` to clean up, then SIGKILL."""
        if self.process is not None and self.process.poll() is None:
            self._signal(signal.CTRL_BREAK_EVENT if sys.platform == "win32" else signal.SIGINT)
            try:
                self.process.wait(timeout=self.grace_s)
            except subprocess.TimeoutExpired:
                self._signal(None)
                self.process.wait()
        self.poll()
        self._remove_leftovers()

    def _signal(self, sig) -> None:
        """``sig`` to the run's process group (None: kill it)."""
        try:
            if sys.platform == "win32":
                self.process.send_signal(sig) if sig is not None else self.process.kill()
            else:
                os.killpg(self.process.pid, signal.SIGKILL if sig is None else sig)
        except (ProcessLookupError, PermissionError):
            pass  # the run has just ended

    def _remove_leftovers(self) -> None:
        parent, name = os.path.split(self.out)
        if not os.path.isdir(parent):
            return
        for entry in set(os.listdir(parent)) - self._before:
            if entry.startswith(f".{name}.") or (entry == name and not self._out_existed):
                path = os.path.join(parent, entry)
                if os.path.isdir(path) and not os.path.islink(path):
                    shutil.rmtree(path, ignore_errors=True)
                else:
                    os.unlink(path)
        if self._made_parent and not os.listdir(parent):
            os.rmdir(parent)
