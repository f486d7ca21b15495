"""Shared pieces of the board-side firmware tests: tool checks and a seeded Sensors stream.

The stream is a rotor turning through the AN1017 hall sequence (CW = sector index increasing:
C B A = 100, 110, 010, 011, 001, 101 — the firmware's own Table 8) at a speed that drifts and
reverses, with edge times inside the period, a pot that moves, S2 presses, and host commands
(Start/Stop, parameter writes inside and outside their ranges) at seeded moments.
"""

from __future__ import annotations

import os
import random
import re
import shlex
import shutil
import subprocess
import sys
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import pytest

from hilbench.protocol import EDGE_NONE, INPUT_S2, MODE_LOCKSTEP, PROTOCOL_VERSION, HostHello, Sensors
from hilbench.targets.sil import FIRMWARE_DIR

DSPIC_PORT = FIRMWARE_DIR / "ports" / "dspic30f2010"


def one_edge(edge_time_100ns: int, inputs: int) -> tuple[tuple[int, int], ...]:
    """Sensors.edges of a period with at most one hall edge (protocol 2's edge time; EDGE_NONE: none)."""
    return () if edge_time_100ns == EDGE_NONE else ((edge_time_100ns, inputs & 7),)

CW_HALLS = (0b100, 0b110, 0b010, 0b011, 0b001, 0b101)


def require_file(path: str, package: str, why: str) -> None:
    """Skip (or fail under HILBENCH_REQUIRE_TOOLS=1) when a file a package installs is missing."""
    if not os.path.exists(path):
        if os.environ.get("HILBENCH_REQUIRE_TOOLS") == "1":
            pytest.fail(f"{path} ({package}) is required (HILBENCH_REQUIRE_TOOLS=1) for {why}")
        pytest.skip(f"{package} not installed ({why})")


def require_tool(name: str, why: str) -> str:
    """Path of a system tool; skip with a one-line reason, or fail under HILBENCH_REQUIRE_TOOLS=1."""
    path = shutil.which(name)
    if path is None:
        if os.environ.get("HILBENCH_REQUIRE_TOOLS") == "1":
            pytest.fail(f"{name} is required (HILBENCH_REQUIRE_TOOLS=1) for {why} but is not on PATH")
        pytest.skip(f"{name} not installed ({why})")
    return path


def port_defines(*make_args: str) -> tuple[str, ...]:
    """The runtime and protocol defines (-DHRT_*, -DHBP_*) the dsPIC Makefile builds with, but the port's
    own HRT_PORT_HW (the host and AVR ports are not hardware ports)."""
    require_tool("make", "the dsPIC Makefile (apt: make)")
    done = subprocess.run(["make", "-s", "-n", "--no-print-directory", "-C", str(DSPIC_PORT), "size", *make_args],
                          capture_output=True, text=True, timeout=60, check=True)
    return tuple(f for f in shlex.split(done.stdout) if re.match(r"-D(HRT|HBP)_", f) and
                 not f.startswith("-DHRT_PORT_HW"))


def python_config(why: str) -> str:
    """The running interpreter's pythonX.Y-config (its base installation's: a harness that embeds
    Python then embeds the one the tests run, whatever else is on PATH), else PATH's; skip or fail as
    `require_tool` (apt: python3-dev, the headers and libpython of the system's python3)."""
    name = f"python{sys.version_info.major}.{sys.version_info.minor}-config"
    own = Path(sys.base_prefix) / "bin" / name
    return require_tool(str(own) if own.exists() else name, f"{why} (apt: python3-dev)")


@dataclass(frozen=True)
class Command:
    """A host command between two periods: "start", "stop", or a parameter write."""

    kind: str
    pairs: tuple[tuple[int, int], ...] = ()


def random_stream(seed: int, periods: int, period_us: int = 50) -> Iterator[Sensors | Command]:
    """Sensors frames (and now and then a Command) of a rotor the firmware can follow or lose."""
    rng = random.Random(seed)
    pos = rng.randrange(6)
    speed = 0.0  # sectors per period, signed
    pot = 600
    period_100ns = period_us * 10
    if rng.random() < 0.5:
        yield Command("start")
    else:
        yield Sensors(0, CW_HALLS[pos] | INPUT_S2, (), 0, (pot, 512, 700))
    phase = 0.0
    hold = 0  # periods left of a stall
    for k in range(periods):
        r = rng.random()
        if hold > 0:
            hold -= 1
        elif r < 0.002:
            speed = rng.uniform(-0.02, 0.02) * (period_us / 50)
        elif r < 0.003:
            speed = 0.0  # a stall: force-commutation every 10 ms, then the stall timeout (0.1 s / 1 s)
            hold = rng.randrange(100_000, 1_500_000) // period_us
        if rng.random() < 0.001:
            pot = rng.randrange(0, 1024)
        phase += speed
        edge = EDGE_NONE
        if phase >= 1.0 or phase <= -1.0:
            step = 1 if phase > 0 else -1
            phase -= step
            pos = (pos + step) % 6
            edge = rng.randrange(0, period_100ns + 1) if rng.random() < 0.9 else 0
        inputs = CW_HALLS[pos]
        if rng.random() < 0.0004:
            inputs = rng.choice((0b000, 0b111))  # an illegal hall state for a period
        if rng.random() < 0.00015:
            inputs |= INPUT_S2
        adc = (pot, rng.randrange(1024), rng.randrange(1024))[: rng.choice((3, 3, 3, 1, 0))]
        yield Sensors((k + 1) & 0xFF, inputs, one_edge(edge, inputs), rng.randrange(0x10000), adc)  # seq 0 went with S2
        c = rng.random()
        if c < 0.0001:
            yield Command(rng.choice(("start", "stop")))
        elif c < 0.0009:
            n = rng.randrange(1, 4)
            pairs = []
            for pid in rng.sample(range(9), n):  # 8 = an unknown id; never the same id twice
                lo, hi = {0: (0, 20000), 1: (0, 20000), 2: (0, 9000), 3: (0, 1), 4: (0, 70), 5: (0, 1),
                          6: (-32768, 32767), 7: (5, 3000), 8: (0, 1)}[pid]
                pairs.append((pid, rng.randint(lo, hi)))
            yield Command("set", tuple(pairs))


def play(stream, targets, period_us: int) -> tuple[int, set]:
    """Feed one stream to every target; every answer must be equal.

    Returns the number of Drives compared and the (state, direction_ccw, fault) triples seen."""
    hello = HostHello(0, PROTOCOL_VERSION, period_us, MODE_LOCKSTEP, 0)
    answers = [t.hello(hello) for t in targets]
    assert all(a == answers[0] for a in answers), answers
    n = 0
    seen = set()
    for item in stream:
        if isinstance(item, Command):
            if item.kind == "start":
                for t in targets:
                    t.start()
            elif item.kind == "stop":
                for t in targets:
                    t.stop()
            else:
                replies = [tuple(t.set_params(item.pairs))[1:] for t in targets]
                assert all(r == replies[0] for r in replies), (item, replies)
                values = [[tuple(t.get_param(i))[1:] for i in range(9)] for t in targets]
                assert all(v == values[0] for v in values), (item, values)
            continue
        drives = [tuple(t.step(item)) for t in targets]
        assert drives[0] == drives[1], (n, item, drives)
        seen.add((drives[0][5], drives[0][7], drives[0][9]))
        n += 1
    return n, seen
