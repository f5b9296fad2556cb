"""A pool worker trims its C heap after an item only when much of it is free
(ident.study.executor.release_free_memory, TRIM_ABOVE_BYTES; docs/performance.md)."""
import sys

import numpy as np
import pytest

from ident.study import executor as E


@pytest.fixture
def trims(monkeypatch):
    calls = []
    monkeypatch.setattr(E, "_MALLOC_TRIM", lambda pad: calls.append(pad) or 1)
    return calls


def test_an_item_that_leaves_little_free_keeps_its_heap(monkeypatch, trims):
    monkeypatch.setattr(E, "_free_heap_bytes", lambda: 30e6)
    assert E._run_and_release(lambda x: x + 1, 41) == 42
    assert trims == []


def test_an_item_that_leaves_much_free_hands_it_back(monkeypatch, trims):
    monkeypatch.setattr(E, "_free_heap_bytes", lambda: E.TRIM_ABOVE_BYTES + 1.0)
    assert E._run_and_release(lambda x: x + 1, 41) == 42
    assert trims == [0]


def test_a_failing_item_still_releases(monkeypatch, trims):
    monkeypatch.setattr(E, "_free_heap_bytes", lambda: 1e9)

    def boom(_):
        raise ValueError("bad item")

    with pytest.raises(ValueError, match="bad item"):
        E._run_and_release(boom, 0)
    assert trims == [0]


def test_without_a_threshold_it_always_trims(monkeypatch, trims):
    monkeypatch.setattr(E, "_free_heap_bytes", lambda: 0.0)
    E.release_free_memory()
    assert trims == [0]


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="glibc mallinfo2")
def test_free_heap_bytes_is_a_count_or_unknown():
    b = E._free_heap_bytes()
    assert b == float("inf") or (np.isfinite(b) and b >= 0)
