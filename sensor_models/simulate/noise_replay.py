"""Standard normal draws kept and replayed where another generator stands in the same state.

Simulations that share a seed (the seed 000 experiment's sensitivity sessions: the same day's
sky under another attitude noise, wobble or installation) draw the same per-pixel noise, frame
after frame: their generators pass through the same states. :class:`NormalReplay` keeps the
draws of one run, keyed by the bit generator's state before each draw, and a generator wrapped by
:meth:`NormalReplay.generator` that reaches a kept state copies the values and jumps to the state
after them instead of drawing them again. The values and every later draw are the same to the
bit as without the replay (the key is the whole state); only the time changes (copying a
1024 x 1024 float64 frame takes about a tenth of drawing it).
"""

from __future__ import annotations

import mmap

import numpy as np

__all__ = ["NormalReplay"]


def _state_key(rng: np.random.Generator) -> tuple:
    """A hashable copy of the generator's whole state."""
    state = rng.bit_generator.state

    def frozen(value):
        if isinstance(value, dict):
            return tuple(sorted((k, frozen(v)) for k, v in value.items()))
        if isinstance(value, np.ndarray):
            return (value.dtype.str, value.shape, value.tobytes())
        return value

    return frozen(state)


class NormalReplay:
    """Standard normal arrays drawn by wrapped generators, up to a memory budget.

    Parameters
    ----------
    max_bytes : int
        Most bytes of draws kept; draws beyond it are made and not kept.

    Attributes
    ----------
    kept_bytes : int
        Bytes kept now.
    replayed, drawn : int
        Arrays copied from the kept draws, and drawn by the generators.
    """

    def __init__(self, max_bytes: int):
        self.max_bytes = max(0, int(max_bytes))
        self.kept_bytes = 0
        self.replayed = 0
        self.drawn = 0
        self._draws: dict = {}

    def generator(self, rng: np.random.Generator) -> "ReplayingGenerator":
        """``rng`` whose :meth:`~ReplayingGenerator.standard_normal` goes through this replay.

        Parameters
        ----------
        rng : numpy.random.Generator

        Returns
        -------
        ReplayingGenerator
        """
        return ReplayingGenerator(rng, self)

    def _lookup(self, key):
        return self._draws.get(key)

    def _keep(self, key, values: np.ndarray, state_after) -> None:
        if key in self._draws or self.kept_bytes + values.nbytes > self.max_bytes:
            return
        self._draws[key] = (_anonymous_copy(values), state_after)
        self.kept_bytes += values.nbytes


def _anonymous_copy(values: np.ndarray) -> np.ndarray:
    """A copy of ``values`` in an anonymous memory map of its own.

    NumPy asks the kernel for transparent huge pages on arrays of 4 MB and more; where the kernel
    compacts memory to find them on the first touch (``defrag`` = ``madvise``), keeping a
    session's draws that way cost 4 to 6 times the draws themselves (9.3 s against 2.4 s for 160
    frames of 1024 x 1024 on the development machine). A plain anonymous map is not advised.
    """
    if values.nbytes == 0:
        return values.copy()
    block = mmap.mmap(-1, values.nbytes)
    out = np.frombuffer(block, dtype=values.dtype).reshape(values.shape)
    np.copyto(out, values)
    return out


class ReplayingGenerator:
    """A :class:`numpy.random.Generator` whose standard normal draws a :class:`NormalReplay` keeps.

    Every other method is the wrapped generator's own (attribute access is forwarded).

    Parameters
    ----------
    rng : numpy.random.Generator
    replay : NormalReplay
    """

    def __init__(self, rng: np.random.Generator, replay: NormalReplay):
        self.rng = rng
        self.replay = replay

    def __getattr__(self, name):
        return getattr(self.rng, name)

    def standard_normal(self, size=None, dtype=np.float64, out=None):
        """:meth:`numpy.random.Generator.standard_normal`, replayed where the state was seen.

        Parameters
        ----------
        size : int or tuple of int, optional
        dtype : {numpy.float64, numpy.float32}, optional
        out : ndarray, optional

        Returns
        -------
        ndarray
            The same values the wrapped generator draws from its present state.
        """
        shape = out.shape if out is not None else (() if size is None else tuple(np.atleast_1d(size).tolist()))
        kind = np.dtype(out.dtype if out is not None else dtype).str
        key = (_state_key(self.rng), shape, kind)
        hit = self.replay._lookup(key)
        if hit is not None:
            values, state_after = hit
            self.rng.bit_generator.state = state_after
            self.replay.replayed += 1
            if out is None:
                return values.copy()
            np.copyto(out, values)
            return out
        values = self.rng.standard_normal(size, dtype=dtype, out=out)
        self.replay.drawn += 1
        if isinstance(values, np.ndarray):
            self.replay._keep(key, values, self.rng.bit_generator.state)
        return values
