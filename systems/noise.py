"""Seeded randomness that is a pure function of (seed, stream, sample index).

Every noise source draws from `sample_rng(seed, stream, k)` for its k-th sample, so the same seed
gives the same run bit for bit, whatever order systems are evaluated in and however often a
context is cloned or re-simulated.
"""

import zlib

import numpy as np


def stream_id(name: str) -> int:
    """A stable integer for a noise stream's name (Python's hash() is salted per process)."""
    return zlib.crc32(name.encode())


def sample_rng(seed: int, stream: str, k: int) -> np.random.Generator:
    """The generator for sample k of the named stream under the scenario seed."""
    return np.random.default_rng([int(seed), stream_id(stream), int(k)])


def sample_index(time: float, period: float) -> int:
    """Index of the periodic sample at `time` for a sampler of the given period (s)."""
    return int(round(time / period))
