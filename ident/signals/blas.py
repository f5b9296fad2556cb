"""One BLAS thread for the small dense solves of identification (DESIGN.md: 2-10x faster on
shared 2-core machines than the default thread pool).

``threadpoolctl.threadpool_limits`` inspects every loaded shared library on each call
(milliseconds; it was ~30 ms per trial of a study, four nested calls per trial). Here the
controller is built once per process, at the first use, and a context nested inside another
one (in the same thread) does nothing.
"""
from __future__ import annotations

import contextlib
import threading

_state = threading.local()
_controller = None
_lock = threading.Lock()


def _get_controller():
    global _controller
    with _lock:
        if _controller is None:
            from threadpoolctl import ThreadpoolController

            _controller = ThreadpoolController()
        return _controller


@contextlib.contextmanager
def one_blas_thread():
    """Context: BLAS limited to one thread; a no-op when threadpoolctl is absent or when an
    enclosing ``one_blas_thread`` of this thread already holds the limit."""
    depth = getattr(_state, "depth", 0)
    if depth:
        _state.depth = depth + 1
        try:
            yield
        finally:
            _state.depth = depth
        return
    try:
        ctrl = _get_controller()
    except ImportError:  # pragma: no cover
        ctrl = None
    limit = ctrl.limit(limits=1, user_api="blas") if ctrl is not None else contextlib.nullcontext()
    with limit:
        _state.depth = 1
        try:
            yield
        finally:
            _state.depth = 0
