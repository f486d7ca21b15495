"""Issue 16, item 8: a duplicated Sensors frame stepped the target twice (at 1 % duplicates a
run "completed" with 114 seq gaps and diverged from the clean run). A repeated seq is answered
with the last Drive, without a step: by the Python targets and by serve()."""

from __future__ import annotations

import random
from typing import Any

import pytest

from hilbench.errors import LinkClosed
from hilbench.protocol import PROTOCOL_VERSION, Drive, HostHello, Sensors
from hilbench.targets.an1017.target import An1017Target
from hilbench.targets.loopback.target import LoopbackTarget
from hilbench.targets.serve import serve

S2 = 0x08


def _stream(n: int, seed: int) -> list[Sensors]:
    """Sensors of n periods: seq k & 0xFF, halls turning, S2 pressed for a few periods, the pot moving."""
    rng = random.Random(seed)
    halls = (1, 3, 2, 6, 4, 5)
    out = []
    for k in range(n):
        inputs = halls[(k // 37) % 6] | (S2 if 10 <= k < 14 else 0)
        out.append(Sensors(k & 0xFF, inputs, (), k & 0xFFFF, (700 + (k // 50), 512 + rng.randrange(3), 640)))
    return out


def _with_duplicates(stream: list[Sensors], seed: int) -> list[Sensors]:
    rng = random.Random(seed)
    out = []
    for s in stream:
        out.append(s)
        if rng.random() < 0.1:
            out.append(s)
    return out


@pytest.mark.parametrize("make", [lambda: LoopbackTarget(), lambda: An1017Target()], ids=["loopback", "an1017"])
def test_item8_targets_answer_a_repeated_seq_without_stepping(make: Any) -> None:
    clean, dup = make(), make()
    hello = HostHello(0, PROTOCOL_VERSION, 50, 0, 0)
    clean.hello(hello)
    dup.hello(hello)
    stream = _stream(3000, 8)
    clean.start() if isinstance(clean, LoopbackTarget) else None
    dup.start() if isinstance(dup, LoopbackTarget) else None
    expected = {}
    for s in stream:
        expected.setdefault(len(expected), clean.step(s))
    got = []
    previous = None
    for s in _with_duplicates(stream, 9):
        d = dup.step(s)
        if previous is not None and s is previous:
            assert d is got[-1]  # the repeat: the very Drive again, no step (for the loopback a step
            continue             # would give an equal Drive: its mapping is idempotent for a repeat)
        got.append(d)
        previous = s
    assert got == [expected[i] for i in range(len(stream))]


class _ScriptedLink:
    """A link that hands serve() a fixed list of messages, then hangs up; it keeps what was sent."""

    name = "scripted"

    def __init__(self, messages: list[Any]) -> None:
        self.messages = list(messages)
        self.sent: list[Any] = []

        class _Stats:
            def as_dict(self) -> dict[str, int]:
                return {}

        self.stats = _Stats()

    def recv_or_none(self, timeout: float | None = None) -> Any:
        if not self.messages:
            raise LinkClosed("scripted: done")
        return self.messages.pop(0)

    def send(self, msg: Any) -> None:
        self.sent.append(msg)

    def reset_sequence(self) -> None:
        pass


def test_item8_serve_answers_a_duplicate_frame_once_stepped() -> None:
    stream = _stream(400, 10)
    duplicated = _with_duplicates(stream, 11)
    n_dup = len(duplicated) - len(stream)
    assert n_dup > 20
    link = _ScriptedLink([HostHello(0, PROTOCOL_VERSION, 50, 0, 0), *duplicated])
    target = An1017Target()
    steps = []
    real_step = target.step

    def counting_step(s: Sensors) -> Drive:
        steps.append(s.seq)
        return real_step(s)

    target.step = counting_step  # type: ignore[method-assign]
    report = serve(target, link)
    assert report.duplicates == n_dup
    drives = [m for m in link.sent if isinstance(m, Drive)]
    assert len(drives) == len(duplicated)  # every frame answered
    assert len(steps) == len(stream)  # but each period stepped once
    reference = An1017Target()
    reference.hello(HostHello(0, PROTOCOL_VERSION, 50, 0, 0))
    unique = [d for i, d in enumerate(drives) if i == 0 or d is not drives[i - 1]]
    assert unique == [reference.step(s) for s in stream]


def test_item8_c_loopback_answers_a_repeated_seq_without_stepping(tmp_path: Any, gcc: str) -> None:
    """The C loopback example answers a repeat with its last Drive. (The loopback mapping is idempotent
    for a repeated Sensors, so this documents the behaviour more than it can catch its absence.)"""
    from c_build import FIRMWARE_DIR, LIBRARY_SOURCES, build_c
    from test_c_loopback import PtyTarget

    exe = build_c([FIRMWARE_DIR / "examples" / "loopback_target.c", *LIBRARY_SOURCES], tmp_path / "loopback_target",
                  extra_flags=("-DHBP_MAX_ADC=3u", "-DHBP_MAX_TELEMETRY=3u"))
    target = PtyTarget(exe)
    try:
        target.ask(HostHello(0, PROTOCOL_VERSION, 1000, 0, 100))
        press = Sensors(1, 1 | S2, (), 0, (1, 2, 3))
        first = target.ask(press)
        again = target.ask(press)  # the duplicate: the same answer, S2 not seen as a second edge
        assert first.state == 2 and again == first
        assert target.ask(Sensors(2, 1, (), 0, (1, 2, 3))).state == 2  # released: still running
        assert target.ask(Sensors(3, 1 | S2, (), 0, (1, 2, 3))).state == 0  # the next press stops
    finally:
        target.close()
