"""Seeded random streams: one seed in, one ``SeedSequence`` stream per fixed block.

Block ``i`` always draws from the ``i``-th child of ``SeedSequence(seed)``, the same
child that ``SeedSequence(seed).spawn(n)[i]`` returns for any ``n > i``. Within a
block, every named input (or error source) draws from its own grandchild stream,
keyed by a stable hash of its name, so that switching one source off leaves the
draws of every other source unchanged (common random numbers across what-if runs).
Workers only decide who computes which block: a result depends on the seed and the
block size, never on ``n_jobs``, the joblib backend or the machine.
"""

from __future__ import annotations

import zlib

import numpy as np

from mtplan._validate import InvalidInput

__all__ = ["as_seed_sequence", "block_sequence", "named_sequence", "named_generator",
           "block_generator"]


def as_seed_sequence(rng=None) -> np.random.SeedSequence:
    """Normalise an ``rng`` argument (SPEC 7) into the root ``SeedSequence``.

    Parameters
    ----------
    rng : None, int, numpy.random.SeedSequence or numpy.random.Generator
        ``None`` draws fresh entropy from the operating system (the entropy is kept
        in the result so the run can be repeated); an int is the seed; a Generator
        gives the root its own ``SeedSequence`` if it has one, else 128 bits drawn
        from it.
    """
    if rng is None:
        return np.random.SeedSequence()
    if isinstance(rng, np.random.SeedSequence):
        return rng
    if isinstance(rng, np.random.Generator):
        seq = getattr(rng.bit_generator, "seed_seq", None)
        if isinstance(seq, np.random.SeedSequence):
            return seq
        return np.random.SeedSequence(rng.integers(0, 2**63, size=2).tolist())
    if isinstance(rng, int | np.integer) and not isinstance(rng, bool) and rng >= 0:
        return np.random.SeedSequence(int(rng))
    raise InvalidInput(
        [
            "The 'rng' parameter must be None, an int >= 0, a numpy.random.SeedSequence or a "
            f"numpy.random.Generator. Got {rng!r} instead."
        ]
    )


def block_sequence(root: np.random.SeedSequence, index: int) -> np.random.SeedSequence:
    """The ``index``-th child of `root`, as ``root.spawn(n)[index]`` gives for a fresh root."""
    return np.random.SeedSequence(
        entropy=root.entropy,
        spawn_key=(*root.spawn_key, int(index)),
        pool_size=root.pool_size,
    )


def named_sequence(seq: np.random.SeedSequence, name: str) -> np.random.SeedSequence:
    """The child of `seq` keyed by a stable hash of `name`."""
    key = zlib.crc32(name.encode("utf-8"))
    return np.random.SeedSequence(
        entropy=seq.entropy, spawn_key=(*seq.spawn_key, key), pool_size=seq.pool_size
    )


def named_generator(seq: np.random.SeedSequence, name: str) -> np.random.Generator:
    """A generator for the input or source `name` inside the block stream `seq`."""
    return np.random.Generator(np.random.PCG64(named_sequence(seq, name)))


def block_generator(root: np.random.SeedSequence, index: int) -> np.random.Generator:
    """The generator of block ``index`` (for block functions that need a single stream)."""
    return np.random.Generator(np.random.PCG64(block_sequence(root, index)))
