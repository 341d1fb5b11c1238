"""A least-recently-used cache bounded by the bytes of the arrays it holds as well as by
its entries.

``functools.lru_cache(maxsize=16)`` of a set-up's geometry holds 16 geometries whatever
their size: at a count field's end-stop one geometry21 set-up's Jacobian and layout held
47 MB, and a live designer that had been shown a few such set-ups kept hundreds of
megabytes after its answers. :func:`array_cache` evicts the least recently used results
until those left hold at most `max_bytes` of numpy arrays (the newest one is always kept).
"""

from __future__ import annotations

import functools
import threading
from collections import OrderedDict

import numpy as np

__all__ = ["array_cache", "array_bytes"]


def array_bytes(value, depth: int = 3) -> int:
    """The bytes of the numpy arrays `value` holds: itself, or in its tuples, lists, dicts
    and attributes, `depth` levels down."""
    if isinstance(value, np.ndarray):
        return int(value.nbytes)
    if depth <= 0:
        return 0
    if isinstance(value, dict):
        items = value.values()
    elif isinstance(value, tuple | list):
        items = value
    elif hasattr(value, "__dict__"):
        items = vars(value).values()
    else:
        return 0
    return sum(array_bytes(v, depth - 1) for v in items)


def array_cache(maxsize: int, max_bytes: int = 16 * 2**20):
    """Decorator: ``functools.lru_cache(maxsize)`` (hashable arguments, the least recently
    used result out first) that also evicts while the results hold more than `max_bytes`
    of arrays (:func:`array_bytes`, counted when each is computed). Has ``cache_clear``
    and ``cache_info`` (hits, misses, entries, bytes)."""
    def decorate(fn):
        cache: OrderedDict = OrderedDict()
        sizes: dict = {}
        lock = threading.Lock()
        counts = {"hits": 0, "misses": 0}

        @functools.wraps(fn)
        def cached(*args, **kwargs):
            key = (args, tuple(sorted(kwargs.items()))) if kwargs else args
            with lock:
                if key in cache:
                    counts["hits"] += 1
                    cache.move_to_end(key)
                    return cache[key]
                counts["misses"] += 1
            value = fn(*args, **kwargs)
            with lock:
                cache[key], sizes[key] = value, array_bytes(value)
                cache.move_to_end(key)
                while len(cache) > 1 and (len(cache) > maxsize
                                          or sum(sizes.values()) > max_bytes):
                    old, _ = cache.popitem(last=False)
                    sizes.pop(old)
            return value

        def cache_clear():
            with lock:
                cache.clear()
                sizes.clear()

        def cache_info() -> dict:
            with lock:
                return {**counts, "entries": len(cache), "bytes": sum(sizes.values())}

        cached.cache_clear, cached.cache_info = cache_clear, cache_info
        return cached
    return decorate
