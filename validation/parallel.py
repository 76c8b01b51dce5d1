"""Run independent tasks of a sweep serially, in local processes, or on a Dask cluster.

Every mode calls the same module-level function on the same arguments and
returns the results in the order of the tasks, so a sweep gives identical
numbers whichever way it runs (only wall and CPU times differ). The tasks
must be pure: their result may depend on their arguments and on files they
read (the reference cache), never on what an earlier task left in the
process.

Modes
-----
``Runner(jobs=1)``
    In this process, one task after the other.
``Runner(jobs=N)``
    ``N`` worker processes on this machine (``concurrent.futures``'
    ``ProcessPoolExecutor``; forked on Linux, spawned elsewhere). Workers
    ignore SIGINT: Ctrl-C reaches the parent, which stops them and raises
    ``KeyboardInterrupt``. A worker whose parent dies (SIGKILL) exits within
    a second instead of staying behind.
``Runner(dask_address="tcp://host:8786")``
    The tasks are submitted to an existing Dask distributed scheduler (the
    optional extra ``dask``). The workers need the same environment (this
    package importable). Connecting gives up after
    :data:`DASK_CONNECT_TIMEOUT` seconds.

In every mode an exception raised by a task comes back to the caller as the
same exception (type, message and attributes), the first one in the order of
the tasks, as a serial run would raise it; the other tasks are cancelled. A
failure of the machinery itself (Dask missing or unreachable, a worker process
killed) raises :class:`RunnerError`, an ``OSError`` so that a command line's
handler of ``OSError`` reports it in one line.

Nothing of the workers' state enters the results: they start from the
parent's modules (fork) or fresh ones (spawn, Dask), read references from the
disk cache or compute them (deterministic), and keep only a per-process memo
of loaded references.

BLAS threads: every task runs with its BLAS on one thread, in every mode
(:func:`single_threaded_blas`). OpenBLAS's result depends on its thread count
in the last bits even for a model of a few unknowns (scipy's Radau, through
``scipy.linalg``'s LU, moves ε in the 9th digit), and that count differs from
process to process: the machine's cores in this one, ``OPENBLAS_NUM_THREADS``
or ``OMP_NUM_THREADS`` as they were when a spawned worker started (a Dask
nanny sets both to 1 in its own process and in its workers' environment), the
parent's when forked. Setting it at run time, not through the environment
(read once, when the library loads), makes it the same everywhere.

``Runner`` is a context manager: inside ``with runner:`` the processes or the
Dask connection are kept from one :meth:`Runner.map` to the next (and a
scheduler that cannot be reached is reported when the block is entered), and
this process's BLAS is on one thread too; outside, each ``map`` sets them up
and tears them down.
"""
from __future__ import annotations

import argparse
import contextlib
import logging
import os
import pickle
import signal
import sys
import threading
import traceback

__all__ = ["Runner", "RunnerError", "add_options", "runner_from_args", "single_threaded_blas",
           "blas_threads", "DASK_CONNECT_TIMEOUT"]

#: Seconds to wait for the Dask scheduler of ``--dask`` before giving up.
DASK_CONNECT_TIMEOUT = 10.0
#: Seconds between a worker's checks that its parent process is still there.
_PARENT_POLL = 0.5


class RunnerError(OSError):
    """The workers could not run the tasks: Dask missing or unreachable, a
    worker process killed, a connection lost. (Not an exception of a task:
    those are re-raised as they are.)"""

    def __init__(self, message: str):
        super().__init__(message)

    def __str__(self):
        return self.args[0]


# -- BLAS threads --------------------------------------------------------------------------

@contextlib.contextmanager
def single_threaded_blas(restore=True):
    """Run the block with every BLAS of this process on one thread (and, with
    ``restore``, put the thread counts back after it). See the module
    docstring: the tasks of a sweep run in it in every mode.

    The thread count is set at run time through ``threadpoolctl`` (OpenBLAS,
    MKL, BLIS; numpy's, scipy's and scikit-sundae's copies alike): the
    environment variables are read only when a library loads.
    """
    import numpy  # noqa: F401  (load numpy's, scipy's and scikit-sundae's BLAS first,
    import scipy.linalg  # noqa: F401  so that the limit reaches each of them)
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


# -- what runs in a worker ------------------------------------------------------------------

def _watch_parent(parent: int) -> None:
    while True:
        threading.Event().wait(_PARENT_POLL)
        if os.getppid() != parent:
            # The parent is gone (killed): nobody will collect our results.
            os._exit(1)


def _init_worker(parent: int) -> None:
    """Initializer of a local worker process."""
    # Ctrl-C in a terminal signals the whole process group: the parent alone
    # handles it (and then stops the workers), so no worker prints a traceback.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    threading.Thread(target=_watch_parent, args=(parent,), daemon=True,
                     name="hfdi-parent-watch").start()


class _Failure:
    """An exception of a task, made to survive pickling.

    An exception that pickles is sent as it is. Some do not unpickle (one
    whose ``__init__`` takes other arguments than ``args``, say): then the
    class, ``args`` and attributes are sent and the exception is rebuilt
    without calling ``__init__``, so that it has the type, message and
    attributes it had in the worker. Failing that, a ``RuntimeError`` naming
    the type carries the message.
    """

    def __init__(self, exc: BaseException):
        self.text = str(exc)
        self.name = f"{type(exc).__module__}.{type(exc).__qualname__}"
        self.remote_traceback = "".join(traceback.format_exception(exc))
        self.plain = self.rebuilt = None
        try:
            data = pickle.dumps(exc)
            back = pickle.loads(data)
            if type(back) is type(exc) and str(back) == self.text:
                self.plain = data
        except Exception:
            pass
        if self.plain is None:
            try:
                self.rebuilt = pickle.dumps((type(exc), exc.args, dict(vars(exc))))
            except Exception:
                pass

    def exception(self) -> BaseException:
        exc = None
        with contextlib.suppress(Exception):
            if self.plain is not None:
                exc = pickle.loads(self.plain)
            elif self.rebuilt is not None:
                cls, args, state = pickle.loads(self.rebuilt)
                exc = cls.__new__(cls, *args)
                exc.args = args
                vars(exc).update(state)
        if exc is None or str(exc) != self.text:
            exc = RuntimeError(f"{self.name}: {self.text}")
        exc.__cause__ = _RemoteTraceback(self.remote_traceback)
        return exc


class _RemoteTraceback(Exception):
    def __init__(self, tb):
        super().__init__(tb)
        self.tb = tb

    def __str__(self):
        return self.tb


def _call(func, args):
    """Run one task in a worker; an exception is returned, not raised."""
    try:
        # no restore: tasks of one Dask worker may run in threads side by side
        with single_threaded_blas(restore=False):
            return True, func(*args)
    except Exception as exc:            # KeyboardInterrupt, SystemExit: not a task's answer
        return False, _Failure(exc)


# -- the runner -----------------------------------------------------------------------------

def _start_method() -> str:
    """``fork`` where it is safe and cheap (Linux, no other thread in this
    process), else ``spawn`` (each worker imports the package afresh)."""
    if sys.platform.startswith("linux") and threading.active_count() == 1:
        return "fork"
    return "spawn"


@contextlib.contextmanager
def _sigint_ignored():
    """Ignore SIGINT while worker processes are started: a spawned or forked
    worker inherits the ignored signal from its first instant (a Ctrl-C
    landing before its initializer ran would print a traceback)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    old = signal.signal(signal.SIGINT, signal.SIG_IGN)
    try:
        yield
    finally:
        signal.signal(signal.SIGINT, old)


@contextlib.contextmanager
def _quiet_distributed():
    """Keep distributed's log records (retries, closed comms) off stderr:
    every failure is reported once, as a :class:`RunnerError`."""
    loggers = [logging.getLogger(n) for n in ("distributed", "tornado", "asyncio")]
    levels = [lg.level for lg in loggers]
    for lg in loggers:
        lg.setLevel(logging.CRITICAL + 1)
    try:
        yield
    finally:
        for lg, level in zip(loggers, levels):
            lg.setLevel(level)


def _import_distributed():
    try:
        with _quiet_distributed():
            import distributed
    except ImportError:
        raise RunnerError("--dask needs Dask distributed: install the 'dask' extra "
                          "(pip install 'hfdi[dask]')") from None
    return distributed


class Runner:
    """Maps a picklable module-level function over tasks.

    Parameters
    ----------
    jobs : int
        Worker processes on this machine; ``1`` runs in this process.
    dask_address : str, optional
        Address of an existing Dask distributed scheduler
        (``tcp://host:8786``); overrides ``jobs``. Needs the ``dask`` extra.
    connect_timeout : float
        Seconds to wait for the scheduler.

    Raises
    ------
    ValueError
        ``jobs`` is not an integer >= 1.
    RunnerError
        ``dask_address`` without the ``dask`` extra installed.
    """

    def __init__(self, jobs: int = 1, dask_address: str | None = None,
                 connect_timeout: float = DASK_CONNECT_TIMEOUT):
        if isinstance(jobs, bool) or int(jobs) != jobs or jobs < 1:
            raise ValueError(f"jobs must be an integer >= 1, got {jobs!r}")
        self.jobs = int(jobs)
        self.dask_address = dask_address or None
        self.connect_timeout = float(connect_timeout)
        if self.dask_address is not None:
            _import_distributed()
        self._depth = 0
        self._pool = None
        self._pool_size = 0
        self._client = None
        self._blas = None

    def __repr__(self):
        where = f"dask_address={self.dask_address!r}" if self.dask_address else \
            f"jobs={self.jobs}"
        return f"Runner({where})"

    @property
    def parallel(self) -> bool:
        """Whether tasks run outside this process."""
        return bool(self.dask_address) or self.jobs > 1

    # -- set-up and tear-down

    def __enter__(self):
        self._depth += 1
        if self._depth == 1:
            if self.dask_address:
                self._connect()
            # this process too (the references computed here, and the work of
            # a caller that runs serially inside the block without map)
            self._blas = single_threaded_blas()
            self._blas.__enter__()
        return self

    def __exit__(self, *exc_info):
        self._depth -= 1
        if self._depth == 0:
            try:
                self.close(kill=exc_info[0] is not None)
            finally:
                blas, self._blas = self._blas, None
                if blas is not None:
                    blas.__exit__(None, None, None)
        return False

    def _connect(self):
        if self._client is None:
            distributed = _import_distributed()
            try:
                # before Client: one made from a malformed address is left half
                # built, and its __del__ hangs at exit
                from distributed.comm import get_address_host_port
                get_address_host_port(self.dask_address)
            except Exception as exc:
                raise RunnerError(f"--dask {self.dask_address!r} is not a scheduler address "
                                  f"like tcp://host:8786 ({exc})") from None
            try:
                with _quiet_distributed():
                    self._client = distributed.Client(self.dask_address,
                                                      timeout=self.connect_timeout,
                                                      set_as_default=False)
            except KeyboardInterrupt:
                raise
            except Exception as exc:
                detail = str(exc).strip().splitlines()[0] if str(exc).strip() else \
                    type(exc).__name__
                raise RunnerError(f"--dask {self.dask_address}: cannot connect to the Dask "
                                  f"scheduler ({detail})") from None
        return self._client

    def _local_pool(self, n_tasks):
        """The worker processes: ``jobs``, or fewer when there are fewer tasks
        (a pool kept from a smaller ``map`` is replaced by a larger one)."""
        workers = min(self.jobs, n_tasks)
        if self._pool is not None and self._pool_size < workers:
            self.close()
        if self._pool is None:
            import multiprocessing
            from concurrent.futures import ProcessPoolExecutor
            context = multiprocessing.get_context(_start_method())
            self._pool = ProcessPoolExecutor(max_workers=workers, mp_context=context,
                                             initializer=_init_worker,
                                             initargs=(os.getpid(),))
            self._pool_size = workers
        return self._pool

    def close(self, kill=False) -> None:
        """Stop the worker processes (at once with ``kill``) and drop the Dask connection."""
        pool, self._pool = self._pool, None
        if pool is not None:
            if kill:
                _terminate(pool)
            else:
                pool.shutdown(wait=True)
        client, self._client = self._client, None
        if client is not None:
            with _quiet_distributed(), contextlib.suppress(Exception):
                client.close(timeout=self.connect_timeout)

    # -- the work

    def map(self, func, tasks, on_result=None, ordered=True) -> list:
        """``[func(*task) for task in tasks]``, in the tasks' order.

        Parameters
        ----------
        func : callable
            A module-level function (picklable by reference).
        tasks : iterable of tuple
            The arguments of each call.
        on_result : callable, optional
            ``on_result(index, result)``, called in this process as the
            results come in (for progress lines, or to write outputs).
        ordered : bool
            Call ``on_result`` in the order of the tasks (a result waits for
            those before it); with ``False``, as each task finishes.

        Returns
        -------
        list
            The results, in the order of the tasks.

        Raises
        ------
        Exception
            The exception of the first task that raised, in the order of the
            tasks (as a serial run would raise it); the tasks after it are
            cancelled.
        RunnerError
            See the class.
        """
        tasks = [tuple(t) for t in tasks]
        if not tasks:
            return []
        if not self.parallel:
            results = []
            for i, task in enumerate(tasks):
                with single_threaded_blas():        # as in a worker (module docstring)
                    results.append(func(*task))
                if on_result is not None:
                    on_result(i, results[-1])
            return results
        with self:
            if self.dask_address:
                return self._map_dask(func, tasks, on_result, ordered)
            return self._map_local(func, tasks, on_result, ordered)

    def _map_local(self, func, tasks, on_result, ordered):
        from concurrent.futures import FIRST_COMPLETED, wait
        from concurrent.futures.process import BrokenProcessPool

        def result_of(future):
            try:
                return future.result()
            except BrokenProcessPool:
                raise RunnerError("a worker process died (killed, or out of memory?); rerun, "
                                  "or use fewer --jobs") from None

        pool = self._local_pool(len(tasks))
        futures = []
        try:
            with _sigint_ignored():
                for task in tasks:
                    futures.append(pool.submit(_call, func, task))
            # No future is cancelled: the pool is killed instead (cancelling
            # first makes Python 3.11's pool thread fail on the killed workers).
            results, failure = _collect(
                futures, result_of, lambda fs: wait(fs, return_when=FIRST_COMPLETED).done,
                on_result, ordered, cancel=None)
        except BaseException:
            self.close(kill=True)
            raise
        if failure is not None:
            # as in a serial run, nothing after the failed task goes on
            self.close(kill=True)
            raise failure.exception()
        return results

    def _map_dask(self, func, tasks, on_result, ordered):
        import distributed
        client = self._connect()

        def lost(exc):
            detail = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
            return RunnerError(f"--dask {self.dask_address}: the cluster failed to run the "
                               f"tasks ({type(exc).__name__}{': ' if detail else ''}{detail})")

        def result_of(future):
            try:
                with _quiet_distributed():
                    return future.result()
            except Exception as exc:                # KilledWorker, lost connection, ...
                raise lost(exc) from None

        def wait_first(fs):
            try:
                with _quiet_distributed():
                    return distributed.wait(fs, return_when="FIRST_COMPLETED").done
            except Exception as exc:
                raise lost(exc) from None

        futures = []
        # distributed.wait looks for "the current client": this one (it is not
        # made the process's default, so that nothing else picks it up)
        with client.as_current():
            try:
                try:
                    with _quiet_distributed():
                        futures = [client.submit(_call, func, task, pure=False)
                                   for task in tasks]
                except Exception as exc:
                    raise lost(exc) from None
                results, failure = _collect(futures, result_of, wait_first, on_result, ordered,
                                            cancel=lambda f: f.cancel())
            except BaseException:
                _cancel(client, futures)
                raise
        if failure is not None:
            _cancel(client, futures)
            raise failure.exception()
        return results


def _cancel(client, futures):
    with _quiet_distributed(), contextlib.suppress(Exception):
        client.cancel(futures)


def _collect(futures, result_of, wait_first, on_result, ordered, cancel):
    """The results of ``futures`` (``(ok, value)`` pairs of :func:`_call`) in
    their order, and the first failure in that order (or ``None``).

    Waits for every task before the first failure (one of them could fail
    too) and drops those after it (``cancel`` on each, when given).
    """
    results = [None] * len(futures)
    pending = {future: i for i, future in enumerate(futures)}
    have, emitted = set(), 0
    failed_at, failure = len(futures), None
    while pending and min(pending.values()) < failed_at:
        if ordered:
            first = min(pending, key=pending.get)
            done = [first] if first.done() else wait_first([first])
        else:
            done = wait_first(list(pending))
        for future in sorted(done, key=lambda f: pending.get(f, -1)):
            i = pending.pop(future, None)
            if i is None or i > failed_at:
                continue
            ok, value = result_of(future)
            if not ok:
                failed_at, failure = i, value
                for later, j in list(pending.items()):
                    if j > i:
                        if cancel is not None:
                            cancel(later)
                        del pending[later]
                continue
            results[i] = value
            have.add(i)
            if on_result is not None and not ordered:
                on_result(i, value)
        if on_result is not None and ordered:
            while emitted in have:
                on_result(emitted, results[emitted])
                emitted += 1
    return results, failure


def _terminate(pool) -> None:
    """Stop a ``ProcessPoolExecutor``'s workers now, running tasks and all."""
    processes = dict(getattr(pool, "_processes", None) or {})
    terminate = getattr(pool, "terminate_workers", None)     # Python >= 3.14
    if terminate is not None:
        with contextlib.suppress(Exception):
            terminate()
    for process in processes.values():
        with contextlib.suppress(Exception):
            process.terminate()
    for process in processes.values():
        with contextlib.suppress(Exception):
            process.join(5.0)
            if process.is_alive():
                process.kill()
                process.join(1.0)
    # the workers are gone: this returns at once, and joins the pool's thread
    # (a later pool is then forked from a process with one thread again)
    pool.shutdown(wait=True)


# -- command-line options -------------------------------------------------------------------

def positive_integer(text):
    """argparse type: an integer >= 1."""
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be an integer >= 1, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be an integer >= 1, got {text!r}")
    return value


def _address(text):
    if not text.strip():
        raise argparse.ArgumentTypeError("must be a scheduler address "
                                         "(e.g. tcp://host:8786), got ''")
    return text.strip()


def add_options(parser) -> None:
    """Add ``--jobs N`` and ``--dask ADDRESS`` to a sub-command's parser."""
    parser.add_argument("--jobs", type=positive_integer, default=1, metavar="N",
                        help="worker processes on this machine (default 1: this process)")
    parser.add_argument("--dask", metavar="ADDRESS", type=_address, default=None,
                        help="run the tasks on an existing Dask distributed cluster "
                             "(scheduler address, e.g. tcp://host:8786; extra 'dask'); "
                             "overrides --jobs")


def runner_from_args(args) -> Runner:
    """The :class:`Runner` of parsed ``--jobs``/``--dask`` options.

    Raises :class:`RunnerError` at once when ``--dask`` is given and the
    ``dask`` extra is not installed.
    """
    return Runner(getattr(args, "jobs", 1), getattr(args, "dask", None))
