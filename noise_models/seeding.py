"""Keyed random streams: one independent generator per (seed, component, episode, resample).

Streams are counter-based (Philox): the key comes from the hashed seed and a stable hash of the
component's name, the episode and resample index sit in the high words of the counter. So

* enabling, removing or reordering one component never shifts another's draws;
* every (seed, component, episode) draw can be reproduced in isolation with :func:`stream`;
* moving to the next episode costs a state write (about 1 µs), not a new ``SeedSequence``.

The global ``np.random`` is never touched.

Example:
    >>> import numpy as np
    >>> s = StreamFactory(seed=0)
    >>> g = s.generator("Friction[geoms=*]")
    >>> s.start(g, "Friction[geoms=*]", episode=3)
    >>> a = g.uniform(size=2)
    >>> b = stream(0, "Friction[geoms=*]", episode=3).uniform(size=2)
    >>> bool((a == b).all())
    True
"""

from __future__ import annotations

import zlib
from collections.abc import Sequence
from typing import Any

import numpy as np

__all__ = ["SEPARATOR", "SeedLike", "StreamFactory", "component_key", "normalize_seed", "reseeded_root", "stream"]

SeedLike = int | Sequence[int] | None


def normalize_seed(seed: object, name: str = "seed") -> tuple[int, ...] | None:
    """Validates a seed (None, a non-negative int or a sequence of them) into a tuple.

    Example:
        >>> normalize_seed(3), normalize_seed((1, 2)), normalize_seed(None)
        ((3,), (1, 2), None)
        >>> normalize_seed(-1)
        Traceback (most recent call last):
        ...
        ValueError: `seed` must be None, a non-negative int or a sequence of them. Received -1.
    """
    if seed is None:
        return None
    items: Sequence[object] = seed if isinstance(seed, (tuple, list)) else (seed,)
    out = []
    for item in items:
        if isinstance(item, bool) or not isinstance(item, (int, np.integer)) or item < 0:
            raise ValueError(f"`{name}` must be None, a non-negative int or a sequence of them. Received {seed!r}.")
        out.append(int(item))
    if not out:
        raise ValueError(f"`{name}` must be None, a non-negative int or a sequence of them. Received {seed!r}.")
    return tuple(out)


def component_key(name: str) -> int:
    """A stable 32-bit key for a component name (``hash()`` is salted per process; crc32 is not)."""
    return zlib.crc32(name.encode("utf-8"))


# Separates the wrap seed from a reset seed in a stream root, so (1, 2) and (1,)+(2,) differ.
SEPARATOR = 0x5EED5EED


def reseeded_root(wrap_seed: tuple[int, ...] | None, reset_seed: tuple[int, ...]) -> tuple[int, ...]:
    """The stream root after ``reset(seed=reset_seed)`` of a component built with ``wrap_seed``.

    Example:
        >>> reseeded_root((1,), (2,)) == (1, SEPARATOR, 2)
        True
    """
    return (*(wrap_seed or ()), SEPARATOR, *reset_seed)


_GOLDEN = 0x9E3779B97F4A7C15
_MASK64 = (1 << 64) - 1


def _root_key(root: tuple[int, ...]) -> np.ndarray:
    return np.random.SeedSequence(list(root)).generate_state(2, np.uint64)


def _philox_key(root_key: np.ndarray, name: str) -> np.ndarray:
    # Philox keys are stream ids: one hashed root per seed, the component's crc32 spread over the
    # first word. One SeedSequence per root (not per component) keeps re-seeding cheap.
    key = root_key.copy()
    key[0] ^= np.uint64(((component_key(name) + 1) * _GOLDEN) & _MASK64)
    return key


def stream(seed: int | Sequence[int], name: str, episode: int, resample: int = 0) -> np.random.Generator:
    """The generator a component named ``name`` uses in ``episode`` (the reference implementation).

    Args:
        seed: the root seed (an int or a tuple of ints, e.g. ``(wrap_seed, reset_seed)``).
        name: the component's stable name (its ``key``).
        episode: episode index since the last seeding (0-based).
        resample: index of the resample within the episode (interval schedules), 0 at reset.
    """
    root = normalize_seed(seed)
    assert root is not None
    bitgen = np.random.Philox(key=_philox_key(_root_key(root), name), counter=[0, 0, resample, episode])
    return np.random.Generator(bitgen)


class StreamFactory:
    """Hands out reusable generators and rewinds them to the (episode, resample) block.

    Args:
        seed: root seed; ``None`` draws fresh OS entropy once (runs then differ from each other but
            stay internally consistent).
    """

    def __init__(self, seed: SeedLike = None) -> None:
        root = normalize_seed(seed)
        if root is None:
            entropy = np.random.SeedSequence().entropy  # an int when drawn from the OS
            assert isinstance(entropy, int)
            root = (entropy % (2**63),)
        self.root: tuple[int, ...] = root
        # Hashed on first use: a factory made only to fix its root, or replaced by a reset seed before any
        # stream is started, never needs it (a SeedSequence is most of a factory's cost).
        self._root_key: np.ndarray | None = None
        self._states: dict[str, dict[str, Any]] = {}

    def generator(self, name: str) -> np.random.Generator:
        """A generator for ``name``; call :meth:`start` before each block of draws."""
        return np.random.Generator(np.random.Philox(key=self._key(name)))

    def _key(self, name: str) -> np.ndarray:
        return np.array(self._state(name)["state"]["key"], dtype=np.uint64)

    def _state(self, name: str) -> dict[str, Any]:
        state = self._states.get(name)
        if state is None:
            if self._root_key is None:
                self._root_key = _root_key(self.root)
            # Python ints, not uint64 arrays: numpy's state setter reads each entry, and a Python int is read
            # several times faster than a numpy scalar is made and read (start runs once per block of draws).
            state = self._states[name] = {
                "bit_generator": "Philox",
                "state": {"counter": [0, 0, 0, 0], "key": [int(k) for k in _philox_key(self._root_key, name)]},
                "buffer": [0, 0, 0, 0],
                "buffer_pos": 4,
                "has_uint32": 0,
                "uinteger": 0,
            }
        return state

    def philox_key(self, name: str) -> list[int]:
        """The Philox key of ``name``'s streams (two Python ints; read only): any Philox generator set to this key, counter
        ``[0, 0, resample, episode]`` and an empty buffer draws what :meth:`start` starts, for code that draws many
        streams with one generator."""
        return self._state(name)["state"]["key"]

    def start(self, gen: np.random.Generator, name: str, episode: int, resample: int = 0) -> None:
        """Rewinds ``gen`` to the first draw of ``(episode, resample)`` for component ``name``."""
        state = self._state(name)
        counter = state["state"]["counter"]
        counter[2] = resample
        counter[3] = episode
        gen.bit_generator.state = state  # copied in by numpy: the template stays reusable
