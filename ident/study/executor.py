"""The one executor seam for batch work: serial, a local process pool, or a Dask cluster.

Every executor maps a top-level (picklable) function over items and yields results in input
order, with a progress bar on stderr where stderr is a terminal (:func:`progress_bars`). Worker
processes run with one BLAS thread each (OPENBLAS_NUM_THREADS=1 via threadpoolctl): on 2-core
machines that was measured 2-10x faster and steadier for the small solves here. Pool workers
end with the process that started them (:func:`_die_with_parent`).
"""
from __future__ import annotations

from concurrent.futures import ProcessPoolExecutor, as_completed
from concurrent.futures.process import BrokenProcessPool
import os
import re
import signal
import sys
import threading
import time
from typing import Callable, Iterable

from ident.outputs import cap_workers
from mocap.io.errors import InputError
from ident.study.lock import drop_inherited


class WorkerLost(RuntimeError):
    """A worker process died (killed, out of memory): the CLI prints one line and exits 1; the
    items finished before it are kept, a rerun resumes."""


def _worker_lost(desc: str) -> WorkerLost:
    return WorkerLost(f"a worker process of the {desc} stage died (killed or out of memory); "
                      "the finished items are kept, rerun to resume")


def progress_bars(enabled: bool = True, stream=None) -> bool:
    """Whether to draw progress bars: asked for, and ``stream`` (stderr) is a terminal. In a
    log, a pipe or a file a bar's carriage returns would pile up; the study's one line per
    stage says what runs instead."""
    stream = sys.stderr if stream is None else stream
    try:
        return bool(enabled) and stream.isatty()
    except (AttributeError, ValueError, OSError):     # closed or replaced stderr
        return False


def _progress(it, total: int, desc: str, enabled: bool):
    if not progress_bars(enabled):
        return it
    from tqdm import tqdm

    return tqdm(it, total=total, desc=desc, unit="task", leave=False)


#: Linux ``prctl`` option: the signal a process gets when the thread that forked it ends
_PR_SET_PDEATHSIG = 1


def _die_with_parent(parent: int, pdeathsig: bool) -> None:
    """Make this pool worker end when the process that started the pool (``parent``) ends,
    however it ends (SIGKILL, out of memory): a worker left behind would hold its caller's
    pipes and the work it was given, and a resume of the study would find it still running.

    Two mechanisms: on Linux the kernel's parent-death signal (``prctl(PR_SET_PDEATHSIG,
    SIGKILL)``; set only when ``pdeathsig``, i.e. the pool was started from the main thread,
    since the signal follows the forking *thread*, and only when ``parent`` forked this process
    itself), and everywhere a daemon thread that ends the process within about 0.2 s once its
    parent process is no longer the one it started under (``os.getppid()`` changes when a
    process is re-parented)."""
    ppid = os.getppid()
    if ppid == parent and pdeathsig and sys.platform.startswith("linux"):
        try:
            import ctypes

            libc = ctypes.CDLL(None, use_errno=True)
            libc.prctl(_PR_SET_PDEATHSIG, int(signal.SIGKILL), 0, 0, 0)
        except (OSError, AttributeError):
            pass
        ppid = os.getppid()        # the parent may have ended before the signal was set
    if ppid != parent and not _alive(parent):
        os._exit(1)

    def watch():
        while os.getppid() == ppid:  # loop until re-parented
            time.sleep(0.2)
        os._exit(1)

    threading.Thread(target=watch, name="jointlab-parent-watch", daemon=True).start()


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except OSError:                # another user's process: alive
        return True
    return True


def _init_pool_worker(parent: int | None = None, pdeathsig: bool = False):
    """A pool worker ignores Ctrl-C: the terminal sends SIGINT to the whole process group, and
    the main process alone reports it (one line) and stops the pool. (The worker was forked
    with SIGINT blocked, see :func:`_sigint_blocked`; a Ctrl-C pending since then is dropped.)
    SIGTERM ends it at once (the main process's handler, inherited by the fork, is reset). It
    lets go of the study lock it inherited and ends with its parent (:func:`_die_with_parent`)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_DFL)
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT, signal.SIGTERM})

    drop_inherited()
    if parent is not None:
        _die_with_parent(parent, pdeathsig)
    _init_worker()


class _sigint_blocked:
    """SIGINT and SIGTERM blocked in this thread while worker processes are forked: a Ctrl-C
    that lands during ``fork`` would otherwise be raised inside the interpreter's at-fork hooks,
    where Python prints and ignores it (in the parent and the child). Unblocked afterwards, a
    pending Ctrl-C is raised here as a plain KeyboardInterrupt (a SIGTERM as what its handler
    raises)."""

    def __enter__(self):
        self.old = None
        if hasattr(signal, "pthread_sigmask"):
            self.old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})
        return self

    def __exit__(self, *exc):
        if self.old is not None:
            signal.pthread_sigmask(signal.SIG_SETMASK, self.old)
        return False


def _release_manager(mgr) -> None:
    """Let a killed pool's manager thread ``mgr`` end. A worker terminated while it was writing a
    result leaves the thread that reads results blocked on the half-written message, and the
    interpreter joins that thread at exit: the command would print its one line and never exit.
    With every worker gone, closing this process's copy of the result pipe's write end turns that
    read into an end-of-file, which the thread takes for a broken pool and ends."""
    if mgr is None:
        return
    mgr.join(1.0)
    if not mgr.is_alive():
        return
    writer = getattr(getattr(mgr, "result_queue", None), "_writer", None)
    try:
        if writer is not None:
            writer.close()
    except OSError:
        pass
    mgr.join(5.0)


def release_free_memory(above: int = 0) -> None:
    """Hand the C heap's free pages back to the system (glibc ``malloc_trim(0)``; nothing
    elsewhere). A worker's big temporary arrays of one item leave free heap pages behind that
    the process would otherwise keep resident until its next item reuses them: trimmed after
    each item, an idle worker holds what it needs, not its largest item's high-water mark (what
    a study's summed peak adds up across processes).

    ``above`` > 0: trim only when the heap's free bytes (glibc ``mallinfo2().fordblks``) exceed
    it (always where that count is not available). Pages handed back are faulted in again, and
    zeroed by the kernel, when the next item allocates: for the study's fit items, about 30 MB
    free after each, that was about 7000 page faults per item and a few per cent of its CPU time
    (docs/performance.md, "Study, per-trial fits")."""
    global _MALLOC_TRIM
    if _MALLOC_TRIM is None:
        _MALLOC_TRIM = False
        if sys.platform.startswith("linux"):
            try:
                import ctypes

                _MALLOC_TRIM = ctypes.CDLL("libc.so.6").malloc_trim
            except (OSError, AttributeError):   # not glibc
                pass
    if _MALLOC_TRIM and (above <= 0 or _free_heap_bytes() > above):
        _MALLOC_TRIM(0)


_MALLOC_TRIM = None
_MALLINFO2 = None

#: free heap bytes above which a pool worker trims its heap after an item
#: (:func:`release_free_memory`): a fit item leaves about 30 MB free, which its next item reuses;
#: a diagnosis item can leave several hundred MB, which an idle worker should not keep
TRIM_ABOVE_BYTES = 96 << 20


def _free_heap_bytes() -> float:
    """Free bytes held in the C heap's arenas (glibc >= 2.33 ``mallinfo2().fordblks``); infinite
    where that count is not available (then a threshold always trims)."""
    global _MALLINFO2
    if _MALLINFO2 is None:
        _MALLINFO2 = False
        if sys.platform.startswith("linux"):
            try:
                import ctypes

                class _Mallinfo2(ctypes.Structure):
                    _fields_ = [(name, ctypes.c_size_t) for name in (
                        "arena", "ordblks", "smblks", "hblks", "hblkhd", "usmblks", "fsmblks",
                        "uordblks", "fordblks", "keepcost")]

                fn = ctypes.CDLL("libc.so.6").mallinfo2
                fn.restype = _Mallinfo2
                fn.argtypes = []
                _MALLINFO2 = fn
            except (OSError, AttributeError):   # not glibc, or glibc < 2.33
                pass
    return float(_MALLINFO2().fordblks) if _MALLINFO2 else float("inf")


def _run_and_release(fn: Callable, item):
    """``fn(item)`` in a pool worker, then :func:`release_free_memory` when more than
    :data:`TRIM_ABOVE_BYTES` of the heap are free."""
    try:
        return fn(item)
    finally:
        release_free_memory(TRIM_ABOVE_BYTES)


def _init_worker():
    os.environ["OPENBLAS_NUM_THREADS"] = "1"
    os.environ["OMP_NUM_THREADS"] = "1"
    try:
        from threadpoolctl import threadpool_limits

        threadpool_limits(1)
    except ImportError:  # pragma: no cover - threadpoolctl is a dependency
        pass


class SerialExecutor:
    """Runs everything in this process (debugging, tiny studies)."""

    name = "serial"
    workers = 1

    def __init__(self, progress: bool = True):
        self.progress = progress

    def map(self, fn: Callable, items: Iterable, desc: str = "work") -> list:
        items = list(items)
        return [fn(x) for x in _progress(items, len(items), desc, self.progress)]

    def submit_map(self, fn: Callable, items: Iterable, desc: str = "work") -> "Pending":
        """:meth:`map` deferred: runs when the result is asked for (one process: nothing
        else could run meanwhile)."""
        items = list(items)

        def each():
            for i, x in enumerate(_progress(items, len(items), desc, self.progress)):
                yield i, fn(x)

        return Pending(lambda: self.map(fn, items, desc), each)

    def close(self):
        pass

    abort = close


class Pending:
    """A mapped batch in flight: ``result()`` waits for it and returns the results in input
    order (the executor's ``map`` semantics: the same errors, raised there); ``each()`` yields
    ``(index, result)`` as the items finish (then ``result()`` returns them all at once)."""

    def __init__(self, wait: Callable[[], list], each: Callable | None = None):
        self._wait, self._done, self._value = wait, False, None
        self._each = each

    def result(self) -> list:
        if not self._done:
            self._value, self._done = self._wait(), True
            self._wait = self._each = None
        return self._value

    def each(self):
        """``(index, result)`` of every item in the order they finish (input order where the
        executor runs them one by one)."""
        if self._done or self._each is None:
            yield from enumerate(self.result())
            return
        values: dict = {}
        items = self._each()
        try:
            for i, r in items:
                values[i] = r
                yield i, r
        finally:        # the caller stopped early (an error, Ctrl-C): the executor's cleanup
            items.close()
        self._value, self._done = [values[i] for i in range(len(values))], True
        self._wait = self._each = None


class PoolExecutor:
    """A local process pool (default: one worker per core)."""

    name = "pool"

    def __init__(self, workers: int | None = None, progress: bool = True):
        self.workers = workers or os.cpu_count() or 1
        self.progress = progress
        self._pool = None

    def map(self, fn: Callable, items: Iterable, desc: str = "work") -> list:
        items = list(items)
        if self.workers <= 1 or len(items) <= 1:
            return SerialExecutor(self.progress).map(fn, items, desc)
        return self.submit_map(fn, items, desc).result()

    def submit_map(self, fn: Callable, items: Iterable, desc: str = "work") -> Pending:
        """Queue every item now (behind the batches submitted before) and return at once:
        this process can do other work while the workers run them; ``result()`` waits."""
        items = list(items)
        if self.workers <= 1 or not items:
            return Pending(lambda: SerialExecutor(self.progress).map(fn, items, desc))
        try:
            with _sigint_blocked():        # workers are forked inside submit()
                if self._pool is None:
                    main = threading.current_thread() is threading.main_thread()
                    self._pool = ProcessPoolExecutor(self.workers, initializer=_init_pool_worker,
                                                     initargs=(os.getpid(), main))
                futs = [self._pool.submit(_run_and_release, fn, x) for x in items]
        except BrokenProcessPool:      # a worker died before this batch was queued
            self._kill()
            raise _worker_lost(desc) from None
        except BaseException:
            self._kill()
            raise
        return Pending(lambda: self._wait(futs, desc), lambda: self._each(futs, desc))

    def _wait(self, futs: list, desc: str) -> list:
        for _ in self._each(futs, desc):
            pass
        return [f.result() for f in futs]

    def _each(self, futs: list, desc: str):
        index = {f: i for i, f in enumerate(futs)}
        try:
            for f in _progress(as_completed(futs), len(futs), desc, self.progress):
                yield index[f], f.result()
        except BrokenProcessPool:
            self._kill()
            raise _worker_lost(desc) from None
        except BaseException:          # Ctrl-C, SIGTERM: stop the workers, no half results
            self._kill()
            raise

    def _kill(self):
        """Stop every worker now (pending work cancelled): SIGKILL, which no worker can ignore
        or be stuck past (a worker holds nothing that needs cleaning up: its outputs are
        written under temporary names and renamed)."""
        pool, self._pool = self._pool, None
        if pool is None:
            return
        procs = list((getattr(pool, "_processes", None) or {}).values())
        manager = getattr(pool, "_executor_manager_thread", None)   # shutdown() drops it
        for p in procs:
            try:
                p.kill()
            except (OSError, AttributeError, ValueError):
                pass
        try:
            pool.shutdown(wait=False, cancel_futures=True)
        except Exception:              # noqa: BLE001 - a broken pool may refuse; the workers are gone
            pass
        for p in procs:
            try:
                p.join(5)
            except (OSError, AssertionError, AttributeError, ValueError):
                pass
        _release_manager(manager)

    def abort(self):
        """Stop the workers now, unfinished work dropped (the command is failing or being
        interrupted: nothing waits for queued items)."""
        self._kill()

    def close(self):
        if self._pool is not None:
            self._pool.shutdown()
            self._pool = None


class DaskExecutor:
    """A Dask distributed cluster (``--scheduler tcp://host:8786``) or a Client passed in."""

    name = "dask"

    def __init__(self, scheduler=None, client=None, progress: bool = True):
        try:
            from distributed import Client
        except ImportError as exc:  # pragma: no cover - depends on the optional extra
            raise ImportError("the Dask executor needs the 'dask' extra: pip install 'jointlab[dask]'") from exc
        self.client = client or Client(scheduler)
        self._own = client is None
        self.progress = progress
        self.client.run(_init_worker)
        self.workers = len(self.client.scheduler_info().get("workers", {})) or 1

    def map(self, fn: Callable, items: Iterable, desc: str = "work") -> list:
        return self.submit_map(fn, items, desc).result()

    def submit_map(self, fn: Callable, items: Iterable, desc: str = "work") -> Pending:
        """Send every item to the cluster now; ``result()`` gathers them."""
        items = list(items)
        if not items:
            return Pending(list)
        futs = self.client.map(fn, items, pure=False)
        return Pending(lambda: self._gather(futs, desc))

    def _gather(self, futs: list, desc: str) -> list:
        from distributed import as_completed

        for _ in _progress(as_completed(futs), len(futs), desc, self.progress):
            pass
        return self.client.gather(futs)

    def close(self):
        if self._own:
            self.client.close()

    abort = close


_SCHEDULER_URL = re.compile(r"^(tcp|tls|ws|wss|ucx|inproc)://[^\s/:]+(:[0-9]{1,5})?/?$")


def make_executor(workers: int | None = None, scheduler: str | None = None, progress: bool = True):
    """``scheduler`` -> Dask; ``workers == 1`` -> serial; else a local process pool of at most
    one worker per CPU (a larger ``workers`` is capped with a note)."""
    if scheduler is not None:
        if not _SCHEDULER_URL.match(str(scheduler)):
            raise InputError(f"--scheduler {scheduler!r} is not a Dask scheduler address "
                             "(e.g. tcp://host:8786)")
    workers = cap_workers(workers)
    if scheduler:
        return DaskExecutor(scheduler, progress=progress)
    if workers == 1:
        return SerialExecutor(progress)
    return PoolExecutor(workers, progress)
