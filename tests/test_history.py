"""The session's speed history (hilbench.bench.history.SpeedHistory): a bounded sequence of samples,
oldest first, that reads as the deque of tuples it replaced did, whichever way samples arrived."""
from __future__ import annotations

import copy
import math
from collections import deque
from collections.abc import Sequence

import numpy as np
import pytest

from hilbench.bench.history import SpeedHistory


def _samples(first: int, n: int, measured: bool = True) -> list[tuple[float, float, float, float]]:
    return [(k * 5e-5, 1500.0, 0.1 * k, 0.2 * k if measured else math.nan) for k in range(first, first + n)]


@pytest.mark.parametrize("maxlen", [1, 7, 64])
@pytest.mark.parametrize("chunks", [[3], [7, 7, 7], [1, 20, 2, 64, 5], [130]])
def test_it_reads_as_a_bounded_deque_of_the_same_samples(maxlen: int, chunks: list[int]) -> None:
    """Chunks (as the C span hands them, the last possibly longer than the ring) and single samples
    (the Python loop) interleaved: the same tuples, in order, as deque(maxlen) of them."""
    reference: deque[tuple[float, float, float, float]] = deque(maxlen=maxlen)
    history = SpeedHistory(maxlen)
    k = 0
    for n in chunks:
        chunk = _samples(k, n)
        history.extend(*(np.array([s[i] for s in chunk]) if i != 1 else chunk[0][1] for i in range(4)))
        reference.extend(chunk)
        k += n
        one = _samples(k, 1)[0]
        history.append(*one)
        reference.append(one)
        k += 1
        assert list(history) == list(reference) and len(history) == len(reference)
        assert [history[i] for i in range(-len(history), len(history))] == list(reference) * 2
        assert list(reversed(history)) == list(reversed(reference)) and history[1:-1] == list(reference)[1:-1]
        assert history.column("plant_rpm") == [s[2] for s in reference]
    assert history.maxlen == maxlen and isinstance(history, Sequence)


def test_a_copy_is_independent_as_a_deque_copy_was() -> None:
    history = SpeedHistory(3)
    for sample in _samples(0, 3):
        history.append(*sample)
    twin = copy.copy(history)
    history.append(*_samples(3, 1)[0])
    assert list(twin) == _samples(0, 3) and list(history) == _samples(1, 3)


def test_a_missing_measurement_reads_as_nan_and_equal_histories_compare_equal() -> None:
    a, b = SpeedHistory(8), SpeedHistory(8)
    for history in (a, b):
        for sample in _samples(0, 5, measured=False):
            history.append(*sample)
    assert all(math.isnan(s[3]) for s in a) and list(a) == list(b)


def test_empty_is_false_and_out_of_range_says_so() -> None:
    history = SpeedHistory(4)
    assert not history and len(history) == 0 and list(history) == []
    with pytest.raises(IndexError):
        history[0]
    history.append(0.0, 1.0, 2.0, 3.0)
    assert history and history[-1] == (0.0, 1.0, 2.0, 3.0)
    with pytest.raises(IndexError):
        history[1]
    with pytest.raises(ValueError):
        SpeedHistory(0)
