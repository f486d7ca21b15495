"""The target kit: one parameter table (checked in the C runtime's order, all or nothing) and one
answer to a repeated seq, used by every built-in target."""

from __future__ import annotations

import pytest

from hilbench.errors import ParamError
from hilbench.protocol import PROTOCOL_VERSION, Access, HostHello, ParamType, Result, Sensors
from hilbench.targets.foc.target import FocTarget
from hilbench.targets.foc.target import available_backends as foc_backends
from hilbench.targets.an1017.target import An1017Target
from hilbench.targets.an1017.target import available_backends as an1017_backends
from hilbench.targets.kit import ParamSpec, ParamTable, RepeatAnswer
from hilbench.targets.loopback.target import LoopbackTarget

Q15, RW, RO = int(ParamType.Q15), int(Access.RW), int(Access.RO)


def table() -> tuple[ParamTable, dict[int, int], list[tuple[dict[int, int], tuple[int, ...]]]]:
    values = {0: 100, 1: 200, 2: 7}
    writes: list[tuple[dict[int, int], tuple[int, ...]]] = []

    def write(new: dict[int, int], written: tuple[int, ...]) -> None:
        writes.append((dict(new), written))
        values.update(new)

    def check(new: dict[int, int], written: tuple[int, ...]) -> tuple[int, int] | None:
        return (written[0], 9) if new[0] + new[1] > 1000 else None  # a constraint across two parameters

    specs = (ParamSpec(0, "a", Q15, RW, 0, 900, "A"), ParamSpec(1, "b", Q15, RW, -5, 900), ParamSpec(2, "v", Q15, RO, 7, 7))
    return ParamTable(specs, values.__getitem__, write, check), values, writes


def test_a_set_is_checked_whole_in_the_c_runtimes_order_before_any_write() -> None:
    params, values, writes = table()
    ok = int(Result.OK)
    assert tuple(params.set(())) == (0, int(Result.BAD_REQUEST), 0, 0)
    assert tuple(params.set(((0, 1),) * 5)) == (0, int(Result.BAD_REQUEST), 0, 0)  # more than 4 pairs
    assert tuple(params.set(((0, 1), (9, 1)))) == (0, int(Result.UNKNOWN_ID), 9, 0)
    assert tuple(params.set(((2, 7),))) == (0, int(Result.READ_ONLY), 2, 0)
    assert tuple(params.set(((0, 5), (1, -6)))) == (0, int(Result.OUT_OF_RANGE), 1, 0)
    assert tuple(params.set(((1, 5), (1, 6)))) == (0, int(Result.BAD_REQUEST), 1, 0)  # the same id twice
    assert tuple(params.set(((1, 600), (0, 500)))) == (0, int(Result.CONSTRAINT), 1, 9)
    assert writes == [] and values == {0: 100, 1: 200, 2: 7}  # nothing written by any refusal
    assert tuple(params.set(((1, 300),))) == (0, ok, 0, 0)  # OK names parameter 0, as hbp_param_set
    assert writes == [({0: 100, 1: 300, 2: 7}, (1,))] and values[1] == 300
    params.ok_names_last = True  # the AN1017 board firmware's bridge names the last parameter written
    assert tuple(params.set(((1, 310), (0, 20)))) == (0, ok, 0, 0)
    assert tuple(params.set(((0, 30), (1, 320)))) == (0, ok, 1, 0)


def test_describe_and_get_speak_the_protocol() -> None:
    params, _, _ = table()
    assert tuple(params.describe(0)) == (0, 0, Q15, RW, 0, 900, 100, "a", "A")  # protocol 3: the unit last
    assert tuple(params.get(1)) == (0, 1, int(Result.OK), 200)
    assert tuple(params.get(5)) == (0, 5, int(Result.UNKNOWN_ID), 0)
    with pytest.raises(ParamError):
        params.describe(5)


def test_a_repeat_gets_the_last_drive_without_a_step() -> None:
    steps: list[int] = []

    def step(sensors: Sensors) -> tuple[int, int]:
        steps.append(sensors.seq)
        return (sensors.seq, len(steps))  # type: ignore[return-value]

    answer = RepeatAnswer(step)
    first = answer.step(Sensors(3, 0, (), 0, ()))
    assert answer.step(Sensors(3, 1, (), 3, ())) is first and steps == [3] and answer.repeats == 1
    answer.step(Sensors(4, 0, (), 0, ()))
    answer.forget()
    answer.step(Sensors(4, 0, (), 0, ()))
    assert steps == [3, 4, 4]


def _targets() -> list[object]:
    out: list[object] = [LoopbackTarget()]
    out += [An1017Target(backend=b) for b in an1017_backends()]
    out += [FocTarget(backend=b) for b in foc_backends()]
    return out


@pytest.mark.parametrize("target", _targets(), ids=lambda t: f"{type(t).__name__}-{getattr(t, 'backend', '')}")
def test_every_built_in_target_answers_a_repeated_seq_once(target: object) -> None:
    target.hello(HostHello(0, PROTOCOL_VERSION, 50, 0, 0))  # type: ignore[attr-defined]
    target.start()  # type: ignore[attr-defined]
    adc = (700, 512, 600)
    drives = [target.step(Sensors(k, 0b001, (), k * 3, adc)) for k in range(1, 40)]  # type: ignore[attr-defined]
    clock = getattr(target, "time_us", None)
    again = target.step(Sensors(39, 0b011, ((123, 0b011),), 999, adc))  # type: ignore[attr-defined]
    assert again == drives[-1] and getattr(target, "time_us", None) == clock  # the firmware did not step
    after = target.step(Sensors(40, 0b001, (), 120, adc))  # type: ignore[attr-defined]
    assert after.seq == 40
