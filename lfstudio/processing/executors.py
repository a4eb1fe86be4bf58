"""Where per-view tasks run: a ``concurrent.futures`` executor, chosen by :func:`open_executor`.

- default: a local process pool (``spawn``, so it is safe under the GUI's threads), one worker per
  core, each single-threaded (OpenCV and LibRaw's OpenMP) so that workers scale with cores; the
  workers die with the process that started them (:func:`die_with_parent`), even after ``kill -9``;
- ``cluster="tcp://HOST:PORT"``: a Dask distributed scheduler; ``client.get_executor()`` is a
  concurrent.futures executor. Workers must see the dataset folder at the same path and have
  lfstudio installed;
- ``workers=0``: run inline in this process (debugging, previews).
"""

from __future__ import annotations

import concurrent.futures as cf
import ctypes
import multiprocessing
import os
import re
import signal
import sys
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Iterator

from lfstudio.errors import InputError


@dataclass
class ExecutorInfo:
    executor: cf.Executor
    workers: int
    description: str
    separate_processes: bool


class InlineExecutor(cf.Executor):
    """Runs each task at submit time in the calling thread."""

    def submit(self, fn, /, *args, **kwargs) -> cf.Future:
        future: cf.Future = cf.Future()
        future.set_running_or_notify_cancel()
        try:
            future.set_result(fn(*args, **kwargs))
        except BaseException as exc:  # noqa: BLE001 - handed to the caller through the future
            future.set_exception(exc)
        return future


def _init_local_worker(parent_pid: int | None = None) -> None:
    # before anything in this fresh process loads LibRaw (its OpenMP reads this once)
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    if parent_pid is not None:
        die_with_parent(parent_pid)


#: prctl option: the signal this process gets when its parent dies (linux/prctl.h)
_PR_SET_PDEATHSIG = 1


def die_with_parent(parent_pid: int) -> None:
    """End this (worker) process when ``parent_pid`` dies, however it dies (``kill -9`` included):
    on Linux the kernel sends SIGKILL (``prctl(PR_SET_PDEATHSIG)``); elsewhere a daemon thread
    watches the parent. A worker killed mid-write leaves only a temporary file (atomic writes),
    which the next run cleans up."""
    if sys.platform.startswith("linux"):
        try:
            libc = ctypes.CDLL(None, use_errno=True)
            ok = libc.prctl(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0) == 0
        except (OSError, AttributeError):
            ok = False
        if ok:
            if os.getppid() != parent_pid:       # it died before prctl took effect
                os._exit(1)
            return
    threading.Thread(target=_watch_parent, args=(parent_pid,), name="parent-watch", daemon=True).start()


def _watch_parent(parent_pid: int, period_s: float = 1.0) -> None:
    while True:
        if os.getppid() != parent_pid:           # re-parented: the parent is gone
            os._exit(1)
        time.sleep(period_s)


def default_workers() -> int:
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:  # pragma: no cover - not Linux
        return max(1, os.cpu_count() or 1)


@contextmanager
def open_executor(workers: int | None = None, cluster: str | None = None,
                  connect_timeout_s: float = 10.0) -> Iterator[ExecutorInfo]:
    """An executor for the run; shut down (or disconnected) on exit."""
    if workers is not None and workers < 0:
        raise InputError("--workers", f"{workers} is negative", "0 (inline) or more")
    if workers and workers > 4 * default_workers():     # each a Python process with its own images in memory
        raise InputError("--workers", f"{workers} worker processes on {default_workers()} cores would only "
                         "compete for them and the memory", f"0 … {4 * default_workers()}")
    if cluster:
        yield from _dask(cluster, connect_timeout_s)
        return
    if workers == 0:
        yield ExecutorInfo(InlineExecutor(), 1, "inline (this process)", False)
        return
    n = workers or default_workers()
    pool = cf.ProcessPoolExecutor(max_workers=n, mp_context=multiprocessing.get_context("spawn"),
                                  initializer=_init_local_worker, initargs=(os.getpid(),))
    try:
        yield ExecutorInfo(pool, n, f"local process pool ({n} worker{'s' if n != 1 else ''})", True)
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


#: a Dask scheduler address: ``tcp://HOST:PORT`` (also tls://, ws://, wss://, ucx://) or ``HOST:PORT``
_DASK_ADDRESS = re.compile(r"(?:(?:tcp|tls|ws|wss|ucx)://)?(?:\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9][A-Za-z0-9.-]*):(\d{1,5})")


def check_cluster_address(address: str) -> None:
    """Refuse a ``--cluster`` value that is no scheduler address before anything connects (Dask would
    try for its whole timeout, then print its own traceback)."""
    m = _DASK_ADDRESS.fullmatch(address.strip())
    if m is None or not 0 < int(m.group(1)) < 65536:
        raise InputError("--cluster", f"{address!r} is not the address of a Dask scheduler",
                         "tcp://HOST:PORT of a running 'dask scheduler', e.g. tcp://192.168.1.20:8786")


def _dask(address: str, timeout_s: float) -> Iterator[ExecutorInfo]:
    check_cluster_address(address)
    try:
        from distributed import Client
    except ImportError:  # pragma: no cover - a dependency
        raise InputError("--cluster", "needs the 'distributed' package (pip install 'dask[distributed]')") from None
    try:
        client = Client(address, timeout=timeout_s, set_as_default=False)
    except (OSError, TimeoutError, ValueError) as exc:
        raise InputError("--cluster", f"cannot reach the Dask scheduler at {address} ({exc})",
                         "tcp://HOST:PORT of a running 'dask scheduler'") from None
    try:
        info: dict[str, Any] = client.scheduler_info()
        threads = sum(int(w.get("nthreads", 1)) for w in info.get("workers", {}).values())
        if threads == 0:
            raise InputError("--cluster", f"the Dask scheduler at {address} has no workers; start some with "
                             f"'dask worker {address}'")
        executor = client.get_executor(pure=False)
        yield ExecutorInfo(executor, threads, f"Dask cluster {address} ({threads} worker threads)", True)
    finally:
        client.close()
