"""Seeded Gaussian noise streams shared by the signal chains and the floor-vibration input."""
from __future__ import annotations

import numpy as np

__all__ = ["child_seed", "stream_seed", "NormalStream", "NOISE_BLOCK"]

NOISE_BLOCK = 4096


def stream_seed(seed: int, purpose: str, index: int = 0) -> int:
    """The int seed of one random stream of a run seed: one per (``seed``, ``purpose``, ``index``).

    ``purpose`` names what the stream is for (an experiment, the identification's excitation, its
    stages); ``index`` counts the streams of one purpose. Different triples give independent streams
    (``SeedSequence`` hashing of all three), so run seed s never replays a stream of run seed s + 1,
    and an experiment's stages never share noise with another purpose's.
    """
    if not isinstance(seed, (int, np.integer)) or isinstance(seed, bool) or seed < 0:
        raise ValueError(f"seed: expected a non-negative int, got {seed!r}")
    if not isinstance(purpose, str) or not purpose:
        raise ValueError(f"purpose: expected a non-empty string, got {purpose!r}")
    if not isinstance(index, (int, np.integer)) or isinstance(index, bool) or index < 0:
        raise ValueError(f"index: expected a non-negative int, got {index!r}")
    tag = [int(b) for b in purpose.encode()]
    state = np.random.SeedSequence([int(seed), int(index), len(tag), *tag]).generate_state(2, np.uint32)
    return int((int(state[0]) << 31) | (int(state[1]) >> 1))


def child_seed(seed, stream: int) -> np.random.SeedSequence:
    """Seed sequence for one stochastic element derived from a master seed.

    ``seed`` may be an int, ``None`` (fresh OS entropy) or a
    ``numpy.random.SeedSequence`` (its child ``stream``, without advancing its spawn counter).
    """
    if isinstance(seed, np.random.SeedSequence):
        return np.random.SeedSequence(seed.entropy, spawn_key=tuple(seed.spawn_key) + (stream,),
                                      pool_size=seed.pool_size)
    if seed is not None and (not isinstance(seed, (int, np.integer)) or seed < 0):
        raise ValueError(f"seed: expected a non-negative int, None or SeedSequence, got {seed!r}")
    return np.random.SeedSequence(seed).spawn(stream + 1)[stream]


class NormalStream:
    """Standard normal deviates of width ``n`` drawn in fixed blocks, so ``take1`` x N == ``take(N)`` bit for bit."""

    def __init__(self, seedseq: np.random.SeedSequence, width: int, block: int = NOISE_BLOCK):
        self._seedseq = seedseq
        self._width = width
        self._block = block
        self.reset()

    def reset(self) -> None:
        """Rewind to the seed."""
        self._rng = np.random.default_rng(self._seedseq)
        self._buf = self._rng.standard_normal((self._block, self._width))
        self._i = 0

    def take1(self) -> np.ndarray:
        """One row of ``width`` deviates."""
        if self._i == self._block:
            self._buf = self._rng.standard_normal((self._block, self._width))
            self._i = 0
        row = self._buf[self._i]
        self._i += 1
        return row

    def take(self, n: int) -> np.ndarray:
        """``n`` rows, the same numbers ``n`` calls of :meth:`take1` would give."""
        return self.take_into(np.empty((n, self._width)))

    def take_into(self, out: np.ndarray) -> np.ndarray:
        """Fill ``out`` ``(n, width)`` (a view may be strided) with the next ``n`` rows of :meth:`take`."""
        n = out.shape[0]
        filled = 0
        while filled < n:
            if self._i == self._block:
                self._buf = self._rng.standard_normal((self._block, self._width))
                self._i = 0
            m = min(n - filled, self._block - self._i)
            out[filled:filled + m] = self._buf[self._i:self._i + m]
            self._i += m
            filled += m
        return out
