"""Run the independent tasks of a sweep here, in local processes or on a Dask cluster.

Every mode calls the same module-level function on the same arguments and
returns the results in the order of the tasks, so a sweep gives identical
numbers whichever way it runs (only wall and CPU times differ). Both
executors, ``concurrent.futures.ProcessPoolExecutor`` (``--jobs N``) and a
``distributed.Client`` (``--dask ADDRESS``, the extra ``dask``), expose
``submit``: :class:`Runner` submits every task and collects the futures in
order.

* A task's exception comes back as the exception a serial run raises: the
  first in the order of the tasks; the later tasks are dropped. A failure of
  the machinery (Dask missing or unreachable, a worker killed) raises
  :class:`RunnerError`, an ``OSError``, which a command line reports in one
  line.
* Local workers ignore SIGINT (Ctrl-C reaches the whole process group): the
  parent stops them and raises ``KeyboardInterrupt``. A worker whose parent
  was killed exits within a second.
* Every task runs with its BLAS on one thread (:func:`single_threaded_blas`):
  OpenBLAS's result depends on its thread count in the last bits, and that
  count would otherwise differ between this process, forked and spawned
  workers and Dask's.
"""
from __future__ import annotations

import contextlib
import logging
import numbers
import os
import signal
import sys
import threading

__all__ = ["Runner", "RunnerError", "single_threaded_blas", "blas_threads",
           "DASK_CONNECT_TIMEOUT"]

#: Seconds to wait for the Dask scheduler of ``--dask`` before giving up.
DASK_CONNECT_TIMEOUT = 10.0


class RunnerError(OSError):
    """The workers could not run the tasks (not an exception of a task)."""

    def __str__(self):
        return self.args[0]


@contextlib.contextmanager
def single_threaded_blas(restore=True):
    """Run the block with every BLAS of this process (numpy's, scipy's,
    scikit-sundae's) on one thread, set at run time through ``threadpoolctl``
    (the environment is read only when a library loads); ``restore`` puts the
    thread counts back after it."""
    import numpy  # noqa: F401  (load the BLAS copies first, so that the limit reaches each)
    import scipy.linalg  # noqa: F401
    with contextlib.suppress(ImportError):
        import sksundae  # noqa: F401
    from threadpoolctl import threadpool_limits
    limits = threadpool_limits(limits=1, user_api="blas")
    try:
        yield
    finally:
        if restore:
            limits.restore_original_limits()


def blas_threads() -> list:
    """The thread count of every BLAS loaded in this process."""
    from threadpoolctl import threadpool_info
    return [info["num_threads"] for info in threadpool_info() if info["user_api"] == "blas"]


def _init_worker(parent: int) -> None:
    """Local worker: Ctrl-C is the parent's to handle; exit when the parent is gone."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)

    def watch():
        while os.getppid() == parent:
            threading.Event().wait(0.5)
        os._exit(1)                     # killed parent: nobody collects our results
    threading.Thread(target=watch, daemon=True).start()


def _task(func, args):
    """One task in a worker: ``(True, result)`` or ``(False, its exception)``, so
    that the exception of a task is told from a failure of the machinery."""
    try:
        # no restore: a Dask worker may run tasks in threads side by side
        with single_threaded_blas(restore=False):
            return True, func(*args)
    except Exception as exc:
        return False, exc


def _start_method() -> str:
    """``fork`` where it is safe (Linux, no other thread here), else ``spawn``."""
    return "fork" if sys.platform.startswith("linux") and threading.active_count() == 1 \
        else "spawn"


@contextlib.contextmanager
def _quiet_dask():
    """distributed's log records (retries, closed comms) off stderr: every
    failure is reported once, as a :class:`RunnerError`."""
    loggers = [logging.getLogger(n) for n in ("distributed", "tornado", "asyncio")]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.CRITICAL + 1)
    try:
        yield
    finally:
        for lg, level in zip(loggers, levels):
            lg.setLevel(level)


def _first_line(exc) -> str:
    text = str(exc).strip()
    return f"{type(exc).__name__}: {text.splitlines()[0]}" if text else type(exc).__name__


def max_jobs() -> int:
    """The most local worker processes a :class:`Runner` takes: four per CPU
    (at least 8). The runs are CPU-bound, so more only cost memory (each
    worker imports numpy, scipy and the compiled path): ``--jobs 100000``
    forked thousands of processes and filled 16 GB."""
    return max(8, 4 * (os.cpu_count() or 1))


class Runner:
    """Maps a module-level function over tasks: here, on ``jobs`` local
    processes, or on the Dask scheduler at ``dask_address`` (which overrides
    ``jobs``). A context manager: inside ``with runner:`` the processes or the
    connection are kept from one :meth:`map` to the next, and this process's
    BLAS is on one thread too.

    Raises
    ------
    ValueError
        ``jobs`` is not an integer in ``[1, max_jobs()]``.
    RunnerError
        ``dask_address`` without the ``dask`` extra installed.
    """

    def __init__(self, jobs: int = 1, dask_address: str | None = None,
                 connect_timeout: float = DASK_CONNECT_TIMEOUT):
        if isinstance(jobs, bool) or not isinstance(jobs, numbers.Integral) \
                or not 1 <= jobs <= max_jobs():
            raise ValueError(f"jobs must be an integer in [1, {max_jobs()}] (four per CPU), "
                             f"got {jobs!r}")
        self.jobs = int(jobs)
        self.dask_address = dask_address or None
        self.connect_timeout = float(connect_timeout)
        if self.dask_address:
            try:
                with _quiet_dask():
                    import distributed  # noqa: F401
            except ImportError:
                raise RunnerError("--dask needs Dask distributed: install the 'dask' extra "
                                  "(pip install 'hfdi[dask]')") from None
        self._executor = None
        self._blas = None
        self._depth = 0

    def __repr__(self):
        return (f"Runner(dask_address={self.dask_address!r})" if self.dask_address
                else f"Runner(jobs={self.jobs})")

    @property
    def parallel(self) -> bool:
        """Whether the tasks run outside this process."""
        return bool(self.dask_address) or self.jobs > 1

    def __enter__(self):
        self._depth += 1
        if self._depth == 1:
            try:
                if self.dask_address:
                    self._open()               # an unreachable scheduler is reported now
            except BaseException:
                self._depth = 0
                raise
            self._blas = single_threaded_blas()
            self._blas.__enter__()
        return self

    def __exit__(self, kind, *_):
        self._depth -= 1
        if self._depth:
            return
        try:
            self._close(kill=kind is not None)
        finally:
            blas, self._blas = self._blas, None
            if blas is not None:
                blas.__exit__(None, None, None)

    def _open(self):
        if self._executor is not None:
            return self._executor
        if self.dask_address:
            import distributed
            from distributed.comm import get_address_host_port
            try:
                # before Client: one made from a malformed address hangs at exit
                get_address_host_port(self.dask_address)
            except Exception as exc:
                raise RunnerError(f"--dask {self.dask_address!r} is not a scheduler address "
                                  f"like tcp://host:8786 ({exc})") from None
            try:
                with _quiet_dask():
                    self._executor = distributed.Client(
                        self.dask_address, timeout=self.connect_timeout, set_as_default=False)
            except Exception as exc:
                raise RunnerError(f"--dask {self.dask_address}: cannot connect to the Dask "
                                  f"scheduler ({_first_line(exc)})") from None
        else:
            import multiprocessing
            from concurrent.futures import ProcessPoolExecutor
            # started with SIGINT ignored, so that a Ctrl-C before the
            # initializer ran cannot print a traceback in a worker
            old = signal.signal(signal.SIGINT, signal.SIG_IGN) \
                if threading.current_thread() is threading.main_thread() else None
            try:
                self._executor = ProcessPoolExecutor(
                    self.jobs, mp_context=multiprocessing.get_context(_start_method()),
                    initializer=_init_worker, initargs=(os.getpid(),))
            finally:
                if old is not None:
                    signal.signal(signal.SIGINT, old)
        return self._executor

    def _close(self, kill=False, futures=()):
        executor, self._executor = self._executor, None
        if executor is None:
            return
        if self.dask_address:
            with _quiet_dask(), contextlib.suppress(Exception):
                if futures:
                    executor.cancel(list(futures))
                executor.close(timeout=self.connect_timeout)
            return
        if kill:
            # stop running tasks too: terminate the workers, then reap the pool
            for process in list((getattr(executor, "_processes", None) or {}).values()):
                with contextlib.suppress(Exception):
                    process.terminate()
                    process.join(5.0)
        executor.shutdown(wait=True, cancel_futures=True)

    def map(self, func, tasks, on_result=None) -> list:
        """``[func(*task) for task in tasks]``, in the tasks' order.

        Parameters
        ----------
        func : callable
            A module-level function (picklable by reference).
        tasks : iterable of tuple
            The arguments of each call.
        on_result : callable, optional
            ``on_result(index, result)``, called here in the order of the tasks
            as their results come in (progress lines, outputs written).

        Raises
        ------
        Exception
            The exception of the first task that raised, in the order of the
            tasks, as a serial run raises it.
        RunnerError
            See the class.
        """
        tasks = [tuple(t) for t in tasks]
        results = []
        if not self.parallel:
            for i, task in enumerate(tasks):
                with single_threaded_blas():          # as in a worker
                    results.append(func(*task))
                if on_result is not None:
                    on_result(i, results[-1])
            return results
        with self:
            executor = self._open()
            extra = {"pure": False} if self.dask_address else {}
            futures = []
            try:
                with _quiet_dask():
                    futures = [executor.submit(_task, func, task, **extra) for task in tasks]
                for i, future in enumerate(futures):
                    try:
                        with _quiet_dask():
                            ok, value = future.result()
                    except Exception as exc:      # a killed worker, a lost connection
                        where = f"--dask {self.dask_address}: the cluster" if \
                            self.dask_address else "a worker process"
                        raise RunnerError(f"{where} failed to run the tasks "
                                          f"({_first_line(exc)}); rerun, or use fewer "
                                          "workers") from None
                    if not ok:
                        raise value               # as in a serial run: nothing after it
                    results.append(value)
                    if on_result is not None:
                        on_result(i, value)
            except BaseException:
                self._close(kill=True, futures=futures)
                raise
        return results
