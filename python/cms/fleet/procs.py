"""A Dask cluster of separate processes on this machine, started from the
command line as on a real cluster: ``dask scheduler`` and ``dask worker``
(the console scripts beside this Python), each its own process with its
own log file. The job reaches it by address (``--scheduler``), exactly as
it reaches a remote one. Used by the fleet's tests and benchmarks.

Every process binds to 127.0.0.1 on a port the system picks; readiness is
the scheduler's address file written and the workers registered with the
scheduler, each waited for with a deadline (never a fixed sleep).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import time
from typing import Optional


class ProcessError(Exception):
    """A process of the cluster did not start: which, and the last line of its log."""


def _tail(path: str) -> str:
    try:
        with open(path, errors="replace") as f:
            lines = [ln.strip() for ln in f if ln.strip()]
    except OSError:
        return "(no log)"
    return lines[-1] if lines else "(empty log)"


def console_script(name: str) -> str:
    """The console script ``name`` of this Python's environment."""
    path = os.path.join(os.path.dirname(sys.executable), name)
    if not os.access(path, os.X_OK):
        raise ProcessError(f"{path}: not found (is the package that installs {name} in this environment?)")
    return path


def wait_until(ready, what: str, proc: subprocess.Popen, log: str, timeout_s: float) -> None:
    """Polls ``ready()`` until true; a ``ProcessError`` naming ``what`` when
    ``proc`` exits first or ``timeout_s`` passes."""
    deadline = time.monotonic() + timeout_s
    while not ready():
        if proc.poll() is not None:
            raise ProcessError(f"{what} exited with status {proc.returncode}: {_tail(log)}")
        if time.monotonic() > deadline:
            raise ProcessError(f"{what} not ready after {timeout_s:.0f} s: {_tail(log)}")
        time.sleep(0.05)


class DaskProcesses:
    """``dask scheduler`` and ``workers`` single-threaded ``dask worker``
    processes, logs and scratch in ``folder``; ``address`` is the
    scheduler's. ``env``: the processes' environment (default this one's).
    A context manager: stopped (terminated, then killed if need be) on
    exit."""

    def __init__(self, folder: str, workers: int, env: Optional[dict] = None, timeout_s: float = 60.0):
        self.folder = folder
        self.env = dict(os.environ if env is None else env)
        self.timeout_s = timeout_s
        self.procs: list[subprocess.Popen] = []
        self.address = ""
        self.workers = workers

    def _start(self, name: str, args: list[str]) -> tuple[subprocess.Popen, str]:
        log = os.path.join(self.folder, f"{name}.log")
        with open(log, "wb") as f:
            p = subprocess.Popen(args, stdout=f, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, env=self.env, cwd=self.folder)
        self.procs.append(p)
        return p, log

    def __enter__(self) -> "DaskProcesses":
        os.makedirs(self.folder, exist_ok=True)
        dask = console_script("dask")
        info = os.path.join(self.folder, "scheduler.json")
        try:
            sched, log = self._start(
                "scheduler",
                [dask, "scheduler", "--host", "127.0.0.1", "--port", "0", "--no-dashboard", "--no-show", "--scheduler-file", info],
            )
            wait_until(lambda: os.path.exists(info) and os.path.getsize(info) > 0, "dask scheduler", sched, log, self.timeout_s)
            with open(info) as f:
                self.address = json.load(f)["address"]
            for i in range(self.workers):
                self._start(
                    f"worker-{i}",
                    [
                        dask, "worker", self.address, "--name", f"worker-{i}", "--nworkers", "1", "--nthreads", "1",
                        "--host", "127.0.0.1", "--no-dashboard", "--local-directory", os.path.join(self.folder, f"worker-{i}"),
                    ],
                )
            self._wait_for_workers()
        except BaseException:
            self.stop()
            raise
        return self

    def _wait_for_workers(self) -> None:
        from dask.distributed import Client

        with Client(self.address, timeout=self.timeout_s) as client:
            deadline = time.monotonic() + self.timeout_s
            while len(client.nthreads()) < self.workers:
                for i, p in enumerate(self.procs[1:]):
                    if p.poll() is not None:
                        raise ProcessError(f"dask worker {i} exited with status {p.returncode}: {_tail(os.path.join(self.folder, f'worker-{i}.log'))}")
                if time.monotonic() > deadline:
                    raise ProcessError(f"{self.workers} dask workers not registered after {self.timeout_s:.0f} s")
                time.sleep(0.05)

    def stop(self) -> None:
        # The workers first, each waited for: a scheduler gone first
        # leaves them retrying it until their timeout.
        for group in (self.procs[1:], self.procs[:1]):
            for p in group:
                if p.poll() is None:
                    p.terminate()
            for p in group:
                try:
                    p.wait(timeout=15)
                except subprocess.TimeoutExpired:
                    p.kill()
                    p.wait()
        self.procs = []

    def __exit__(self, *exc) -> None:
        self.stop()
