"""AN1017 SVM: sine table, reference duty vectors (facts §1.3), waveform shape and THD."""

from __future__ import annotations

import math

import numpy as np
import pytest

from hilbench.targets.an1017.svm import SINE_TABLE, svm, svm_sector


def test_sine_table_shape_and_end_values():
    assert len(SINE_TABLE) == 172
    assert SINE_TABLE[:5] == (0, 201, 401, 602, 803)
    assert SINE_TABLE[-3:] == (28174, 28276, 28377)
    for i in (0, 57, 100, 171):
        assert SINE_TABLE[i] == round(32767 * math.sin(math.radians(i * 60 / 171)))


@pytest.mark.parametrize(
    "volts, angle, sector, duties",
    [
        (0, 0x0000, 1, (499, 499, 499)),
        (16384, 0x0000, 1, (714, 284, 284)),
        (16384, 0x1555, 1, (747, 499, 251)),
        (28300, 0x1555, 1, (927, 499, 71)),
        (32767, 0x4000, 2, (499, 927, 71)),
        (16384, 0x8000, 4, (284, 714, 714)),
        (10000, 0xE000, 6, (644, 354, 567)),
        (20000, 0x0AAA, 1, (791, 361, 207)),
    ],
)
def test_reference_duty_vectors(volts, angle, sector, duties):
    assert svm_sector(angle) == sector
    assert svm(volts, angle) == duties


def test_sector_boundaries():
    assert [svm_sector(a) for a in (0, 0x2AA9, 0x2AAA, 0x5555, 0x8000, 0xAAAA, 0xD554, 0xD555, 0xFFFF)] == [
        1, 1, 2, 3, 4, 5, 5, 6, 6,
    ]


def test_zero_volts_is_fifty_percent_everywhere():
    for a in range(0, 65536, 97):
        assert svm(0, a) == (499, 499, 499)


def _cycle(volts: int, n: int = 1024) -> np.ndarray:
    return np.array([svm(volts, (k * 65536) // n) for k in range(n)], dtype=float)


def test_phase_duties_are_saddle_shaped():
    d = _cycle(int(0.8 * 28300))
    a = d[:, 0]
    # centred SVM = sine plus a third-harmonic-like triangle: flat-topped "saddle" with two humps
    peak_idx = int(np.argmax(a))
    top = a[a > a.max() - 15]
    assert a.max() < 1000 and a.min() > 0
    # the top is wide (> 60° of 360°) and dips between the two humps (60° apart around 0°)
    assert len(top) > 1024 * 60 / 360
    centre = a[0]  # phase 1 axis: angle 0 lies between the humps at ±30°
    assert centre < a.max() - 5
    assert peak_idx != 0
    # average duty is 50 % (zero vectors split equally)
    assert abs(a.mean() - 499) < 2


def test_line_to_line_is_sinusoid_low_thd():
    n = 1024
    d = _cycle(int(0.8 * 28300), n)
    vab = d[:, 0] - d[:, 1]
    spec = np.abs(np.fft.rfft(vab)) / n
    fund = spec[1]
    harm = np.sqrt(np.sum(spec[2 : n // 2] ** 2))
    assert harm / fund < 0.02
    # line-line peak ≈ v·tpwm: 0.8·28300/32768 · 998 (facts §1.3 meaning) within table quantisation
    expected = 0.8 * 28300 / 32768 * 998
    assert abs(2 * fund - expected) / expected < 0.01


@pytest.mark.parametrize("volts", [-1, 0, 1, 163, 16384, 22640, 28299, 28300, 28301, 32767])
def test_c_core_svm_equals_svm_at_every_angle(volts):
    # the compiled core's SVM must agree with the readable one everywhere, including volts = -1
    # (the CCW start-up value) and amplitudes above the 0.866 clamp
    core = _c_core()
    for a in range(65536):
        assert core.svm(volts, a) == svm(volts, a), (volts, a)


def test_c_core_svm_equals_svm_random_pairs():
    import random

    core = _c_core()
    rng = random.Random(2)
    for _ in range(50_000):
        v, a = rng.randrange(-1, 32768), rng.randrange(65536)
        assert core.svm(v, a) == svm(v, a), (v, a)
    assert core.svm(16384, 0x1555) == (747, 499, 251)  # facts §1.3 vector


def _c_core():
    from conftest import require_c_an1017

    if not require_c_an1017():
        pytest.skip("compiled AN1017 core not built")
    from hilbench.targets.an1017 import _core

    return _core
