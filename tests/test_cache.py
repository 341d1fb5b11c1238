"""The cache bounded by the bytes of its results' arrays (:mod:`mtplan._cache`)."""

from __future__ import annotations

import numpy as np

from mtplan._cache import array_bytes, array_cache


def test_array_bytes_counts_arrays_in_containers_and_attributes():
    class Holder:
        def __init__(self):
            self.a, self.b = np.zeros(10), {"c": (np.zeros(5, dtype=np.float32), 3)}

    assert array_bytes(Holder()) == 80 + 20
    assert array_bytes([np.zeros(2), "text", None]) == 16


def test_evicts_the_least_recently_used_beyond_its_bytes_and_keeps_the_newest():
    calls = []

    @array_cache(maxsize=10, max_bytes=8 * 1000)
    def block(n):
        calls.append(n)
        return np.zeros(n)

    block(400), block(400), block(500)  # 3200 + 4000 bytes: both kept
    assert calls == [400, 500] and block.cache_info()["entries"] == 2
    block(400)  # used again: 500 is now the least recently used
    block(600)  # 4800 more: 500 goes (the least recently used), 400 stays (8000 in all)
    assert block.cache_info()["entries"] == 2 and block.cache_info()["bytes"] == 8000
    block(400)
    assert calls == [400, 500, 600]
    block(2000)  # alone over the bytes: still kept (the newest)
    assert block.cache_info()["entries"] == 1 and block.cache_info()["bytes"] == 16000
    block(2000)
    assert calls == [400, 500, 600, 2000]


def test_evicts_beyond_its_entries():
    @array_cache(maxsize=2)
    def same(n):
        return n

    same(1), same(2), same(3)
    assert same.cache_info()["entries"] == 2
    same.cache_clear()
    assert same.cache_info()["entries"] == 0
