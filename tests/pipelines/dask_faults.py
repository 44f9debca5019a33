"""What the fault tests of the Dask runs (``batch``, ``solve --scheduler``) share: a worker plugin that stalls one
write of each chosen output halfway, so a kill lands mid-write deterministically, and the waits around it.

The plugin truncates the temporary file of the first write of a chosen output to half, records its process id in
a marker file and waits there, the way a process killed mid-write leaves it; the retry writes normally.
"""

import contextlib
import importlib
import os
import subprocess
import sys
import time
from pathlib import Path

import cloudpickle
from distributed.diagnostics.plugin import WorkerPlugin

from camcal.base.atomic import TEMPORARY_TAG

cloudpickle.register_pickle_by_value(sys.modules[__name__])  # the plugin below, for the worker processes


class StallOnce(WorkerPlugin):
    """Worker plugin: the first write of each chosen output (by ``module.function(path, ...)``) stops halfway."""

    name = "camcal-test-stall-once"

    def __init__(self, module: str, function: str, markers: dict[str, str]) -> None:
        self.module, self.function = module, function
        self.markers = markers  # output file name -> marker file (created by the one write that stalls)

    def setup(self, worker) -> None:
        target = importlib.import_module(self.module)
        unstalled = f"_unstalled{self.function}"
        original = getattr(target, unstalled, getattr(target, self.function))
        setattr(target, unstalled, original)
        markers = self.markers

        def stalling_write(path, *args):
            original(path, *args)
            output = Path(path).name.split(f".{TEMPORARY_TAG}.")[0][1:]
            if output not in markers:
                return
            try:
                handle = os.open(markers[output], os.O_CREAT | os.O_EXCL | os.O_WRONLY)
            except FileExistsError:
                return  # stalled once already: this is the retry
            os.truncate(path, os.path.getsize(path) // 2)
            os.write(handle, str(os.getpid()).encode())
            os.close(handle)
            time.sleep(600)

        setattr(target, self.function, stalling_write)


def wait_for_pid(marker: Path, process: subprocess.Popen, seconds: float = 180) -> int:
    """The process id the stalled write recorded in ``marker``; fails if ``process`` ends first."""
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        text = marker.read_text() if marker.exists() else ""
        if text:
            return int(text)
        assert process.poll() is None, "the run ended before the write stalled"
        time.sleep(0.05)
    raise AssertionError(f"no write stalled on {marker.name}")


def _running_keys(dask_worker):
    return [str(task.key) for task in dask_worker.state.all_running_tasks]


def drain(dask) -> None:
    """Wait until the scheduler holds no task and no worker runs one (a killed client's tasks run to their end)."""
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        if not dask.run_on_scheduler(lambda dask_scheduler: len(dask_scheduler.tasks)) and not any(
                dask.run(_running_keys, on_error="ignore").values()):
            return
        time.sleep(0.1)


def temporaries(folder: Path) -> list[str]:
    """camcal's temporary files below ``folder``, relative to it."""
    return sorted(p.relative_to(folder).as_posix() for p in folder.rglob("*") if TEMPORARY_TAG in p.name)


@contextlib.contextmanager
def workers_elsewhere(client, folder: Path):
    """The cluster's workers in ``folder`` for the block (as a farm's: they do not share the client's working
    directory), then back where they were; the block must leave ``folder`` empty."""
    folder.mkdir(parents=True, exist_ok=True)
    before = client.run(os.getcwd)
    client.run(os.chdir, str(folder))
    try:
        yield
    finally:
        for worker, cwd in before.items():
            client.run(os.chdir, cwd, workers=[worker])
    assert not list(folder.iterdir()), "a worker wrote into its own working directory"
