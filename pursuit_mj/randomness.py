"""Counter-based random numbers, one independent stream per world.

A value is a hash (splitmix64) of (world key, tick, index, stream), so what one world
draws never depends on how many other worlds run beside it or on what they draw, and a
world's numbers at step t of an episode are the same whenever that episode is replayed.
Everything is vectorised with numpy over worlds; nothing loops in Python.

Keys are uint64 per world, derived from episode seeds with `world_keys` (a `domain` number
keeps the streams of different users of one seed apart); ticks count decision steps.
"""

from __future__ import annotations

import math

import numpy as np

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_MIX1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX2 = np.uint64(0x94D049BB133111EB)
TICK = np.uint64(0xD1B54A32D192ED03)  # odd multiplier that spreads tick counters
N_STREAMS = 8  # streams per (key, tick): `stream` must be in 0..N_STREAMS-1


def splitmix64(x: np.ndarray) -> np.ndarray:
    """The splitmix64 finaliser of uint64 values (any shape), elementwise (wraps on overflow)."""
    with np.errstate(over="ignore"):
        z = x + _GOLDEN
        z = (z ^ (z >> np.uint64(30))) * _MIX1
        z = (z ^ (z >> np.uint64(27))) * _MIX2
    return z ^ (z >> np.uint64(31))


def world_keys(seeds: np.ndarray, domain: int = 0) -> np.ndarray:
    """uint64 keys (k,) from non-negative integer seeds (k,); another `domain`, other keys."""
    s = np.asarray(seeds).astype(np.uint64)
    with np.errstate(over="ignore"):
        return splitmix64(splitmix64(s) ^ (np.uint64(domain) * TICK))


def hash_uniform(key: np.ndarray, tick: np.ndarray, shape: int | tuple[int, ...], stream: int) -> np.ndarray:
    """Uniform [0, 1) numbers (W, *shape) from world keys (W,) uint64 and ticks (W,) integers.

    The value at [w, i...] depends only on (key[w], tick[w], flat index i, stream).
    """
    if not 0 <= stream < N_STREAMS:
        raise ValueError(f"hash_uniform stream: expected 0..{N_STREAMS - 1}, got {stream!r}")
    shape = (shape,) if isinstance(shape, (int, np.integer)) else tuple(shape)
    n = math.prod(shape)
    idx = np.arange(n, dtype=np.uint64) * np.uint64(N_STREAMS) + np.uint64(stream)
    key = np.asarray(key, np.uint64)
    tick = np.asarray(tick).astype(np.uint64)
    with np.errstate(over="ignore"):
        x = splitmix64(key[:, None] ^ (tick[:, None] * TICK)) + idx[None, :] * _GOLDEN
    z = splitmix64(x)
    return ((z >> np.uint64(11)).astype(np.float64) * 2.0**-53).reshape((len(key),) + shape)


def hash_uniforms(key: np.ndarray, tick: np.ndarray, shape: int | tuple[int, ...], streams: tuple[int, ...]) -> np.ndarray:
    """`hash_uniform` of several streams at once, (len(streams), W, *shape): the same numbers
    (integer arithmetic throughout), with the per-world part of the hash worked out once."""
    for stream in streams:
        if not 0 <= stream < N_STREAMS:
            raise ValueError(f"hash_uniform stream: expected 0..{N_STREAMS - 1}, got {stream!r}")
    shape = (shape,) if isinstance(shape, (int, np.integer)) else tuple(shape)
    n = math.prod(shape)
    idx = np.arange(n, dtype=np.uint64) * np.uint64(N_STREAMS) + np.array(streams, np.uint64)[:, None]  # (S, n)
    key = np.asarray(key, np.uint64)
    tick = np.asarray(tick).astype(np.uint64)
    with np.errstate(over="ignore"):
        x = splitmix64(key[:, None] ^ (tick[:, None] * TICK))[None] + idx[:, None, :] * _GOLDEN  # (S, W, n)
    z = splitmix64(x)
    return ((z >> np.uint64(11)).astype(np.float64) * 2.0**-53).reshape((len(streams), len(key)) + shape)


def hash_normal(key: np.ndarray, tick: np.ndarray, shape: int | tuple[int, ...], stream: int) -> np.ndarray:
    """Standard normal numbers (W, *shape) (Box-Muller on streams `stream` and `stream + 1`)."""
    u1 = hash_uniform(key, tick, shape, stream)
    u2 = hash_uniform(key, tick, shape, stream + 1)
    return np.sqrt(-2.0 * np.log1p(-u1)) * np.cos(2.0 * np.pi * u2)


class WorldRandom:
    """Generator-like draws for one decision step of W worlds: keys (W,) uint64, ticks (W,).

    Offers the two `np.random.Generator` methods perception uses, `random(size)` and
    `normal(loc, scale, size)`, with size[0] == W (one row per world). Make a fresh one per
    step: its k-th call draws from sub-key k, so calls in a fixed order give fixed numbers.
    """

    def __init__(self, keys: np.ndarray, ticks: np.ndarray):
        self.keys = np.asarray(keys, np.uint64)
        self.ticks = np.asarray(ticks)
        if self.keys.ndim != 1 or self.ticks.shape != self.keys.shape:
            raise ValueError(f"WorldRandom: expected keys and ticks of one shape (W,), got {self.keys.shape} and {self.ticks.shape}")
        self._calls = 0

    def _count(self, size) -> tuple[int, ...]:
        """`size` checked (W, ...), and one more call counted."""
        size = _checked_size(size, len(self.keys))
        if size[0] != len(self.keys):
            raise ValueError(f"WorldRandom: size {size} must start with the number of worlds {len(self.keys)}")
        self._calls += 1
        return size

    def _next_keys(self, size) -> tuple[np.ndarray, tuple[int, ...]]:
        size = self._count(size)
        with np.errstate(over="ignore"):
            keys = splitmix64(self.keys ^ (np.uint64(self._calls) * _GOLDEN))
        return keys, size[1:]

    def random(self, size) -> np.ndarray:
        """Uniform [0, 1) numbers of shape `size` (W, ...)."""
        keys, rest = self._next_keys(size)
        return hash_uniform(keys, self.ticks, rest, 0)

    def skip(self, size) -> None:
        """Count a draw of shape `size` (W, ...) without making it: the calls after it draw what
        they would after `random(size)` or `normal(..., size)` (for a caller that would
        discard the numbers)."""
        self._count(size)

    def normal(self, loc: float = 0.0, scale: float = 1.0, size=None) -> np.ndarray:
        """Normal numbers (mean loc, std scale) of shape `size` (W, ...)."""
        keys, rest = self._next_keys(size)
        return loc + scale * hash_normal(keys, self.ticks, rest, 0)


def _checked_size(size, n_worlds: int) -> tuple[int, ...]:
    """`size` (an int or a sequence of ints) as a tuple of non-negative ints, at least one; ValueError
    naming it otherwise (numpy's size=None, one number, has no row per world)."""
    shape = (size,) if isinstance(size, (int, np.integer)) else size
    ok = isinstance(shape, (tuple, list)) and len(shape) > 0 and all(
        isinstance(n, (int, np.integer)) and not isinstance(n, (bool, np.bool_)) and n >= 0 for n in shape)
    if not ok:
        raise ValueError(f"WorldRandom: size {size!r}: expected a shape ({n_worlds}, ...) of non-negative integers, "
                         f"one row per world")
    return tuple(int(n) for n in shape)
