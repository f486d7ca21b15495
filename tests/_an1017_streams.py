"""Seeded random Sensors streams for the AN1017 target, and players that record every answer.

A script holds, per lockstep step, a Sensors plus occasional host actions: hall edges at random
times inside the period (including at 0, without a time, and past the period's end), direction
reversals, invalid hall states (000, 111), stalls, S2 presses (also held through the bootstrap),
pot changes, gain writes (accepted and refused), phase-advance and reference-override writes,
host start/stop, watchdog trips, and probes of the firmware state (time, Phase, duty registers).
tests/test_an1017_core.py plays them on the C core and on the Python reference and requires
identical answers; tests/test_an1017_build.py does the same for other motor builds.
"""

from __future__ import annotations

import random

from _firmware import one_edge
from hilbench.protocol import Sensors
from hilbench.targets.an1017.target import (
    PARAM_KD,
    PARAM_KI,
    PARAM_KP,
    PARAM_PH_ADV_DEG,
    PARAM_PH_ADV_ON,
    PARAM_REF_OVR,
    PARAM_REF_OVR_ON,
    PARAM_STALL_MS,
    An1017Target,
)

EDGE_NONE = 0xFFFF
S2 = 0x08
# CW order of hall states (C B A), Table 8: sector 0..5
HALL_OF_SECTOR = (0b100, 0b110, 0b010, 0b011, 0b001, 0b101)


def random_script(seed: int, n_steps: int, step_us: int) -> list[tuple]:
    """Per step: ("sensors", Sensors) plus host actions ("start"/"stop"/"watchdog"/"params", …)."""
    rng = random.Random(seed)
    period_100ns = step_us * 10
    script: list[tuple] = []
    sector = 0
    hall = HALL_OF_SECTOR[0]
    next_edge_us = 300.0
    dwell_us = 1500.0
    direction = 1
    pot = 800
    s2_left = 0  # periods S2 stays down
    t_us = 0.0
    for k in range(n_steps):
        t0, t1 = t_us, t_us + step_us
        # occasional regime changes of the rotor stream
        r = rng.random()
        if r < 0.002:
            dwell_us = rng.choice((120.0, 400.0, 900.0, 1500.0, 3000.0, 6000.0, 250_000.0))
        elif r < 0.003:
            direction = -direction
        edge = EDGE_NONE
        while t0 <= next_edge_us < t1:
            x = rng.random()
            if x < 0.01:
                hall = rng.choice((0b000, 0b111))  # invalid state
            elif x < 0.015:
                hall = rng.randrange(8)  # any jump
            else:
                sector = (sector + direction) % 6
                hall = HALL_OF_SECTOR[sector]
            edge = int((next_edge_us - t0) * 10)
            next_edge_us += dwell_us * rng.uniform(0.7, 1.3)
        if edge != EDGE_NONE:
            y = rng.random()
            if y < 0.05:
                edge = EDGE_NONE  # hall changed, no time given
            elif y < 0.08:
                edge = 0
            elif y < 0.10:
                edge = rng.randrange(period_100ns, 0xFFFF)  # past the period: clamped
        elif rng.random() < 0.002:
            edge = rng.randrange(0, period_100ns)  # a time without a hall change
        if rng.random() < 0.01:
            pot = rng.choice((0, 100, 300, 511, 512, 513, 700, 900, 1023, rng.randrange(1024)))
        elif rng.random() < 0.05:
            pot = min(1023, max(0, pot + rng.randrange(-3, 4)))
        if s2_left == 0 and rng.random() < 0.0015:
            s2_left = rng.randrange(1, 400)
        inputs = hall | (S2 if s2_left else 0) | (0x10 if rng.random() < 0.01 else 0)
        s2_left = max(0, s2_left - 1)
        z = rng.random()
        if z < 0.001:
            script.append(("start",))
        elif z < 0.0015:
            script.append(("stop",))
        elif z < 0.0017:
            script.append(("watchdog",))
        elif z < 0.004:
            pid = rng.choice(
                (PARAM_KP, PARAM_KI, PARAM_KD, PARAM_PH_ADV_ON, PARAM_PH_ADV_DEG, PARAM_REF_OVR_ON, PARAM_REF_OVR,
                 PARAM_STALL_MS)
            )
            value = {
                PARAM_KP: rng.randrange(0, 30000),
                PARAM_KI: rng.randrange(0, 3000),
                PARAM_KD: rng.randrange(0, 20000),  # sometimes breaks a constraint → refused
                PARAM_PH_ADV_ON: rng.randrange(2),
                PARAM_PH_ADV_DEG: rng.randrange(61),
                PARAM_REF_OVR_ON: rng.randrange(2),
                PARAM_REF_OVR: rng.randrange(-32768, 32768),
                PARAM_STALL_MS: rng.choice((10, 55, 100, 1000)),
            }[pid]
            script.append(("params", ((pid, value),)))
        script.append(("sensors", Sensors(k & 0xFF, inputs, one_edge(edge, inputs), k & 0xFFFF, (pot, 512, 700))))
        if rng.random() < 0.003:
            script.append(("probe",))  # look at the firmware state mid-stream
        t_us = t1
    return script


def probe(target: An1017Target) -> tuple:
    """Time, Phase, the active and the pending duty registers, as the firmware holds them now."""
    fw = target.fw
    return ("probe", fw.t, fw.phase, fw.duties(), fw.pending_duties(), fw.ref_speed, fw.pot_code)


def play(target: An1017Target, script: list[tuple]) -> list:
    out: list = []
    for item in script:
        kind = item[0]
        if kind == "sensors":
            out.append(target.step(item[1]))
        elif kind == "start":
            target.start()
        elif kind == "stop":
            target.stop()
        elif kind == "watchdog":
            out.append(target.watchdog_trip())
        elif kind == "probe":
            out.append(probe(target))
        else:
            out.append(target.set_params(item[1]))
    return out


def play_with_advances(target: An1017Target, script: list[tuple], seed: int) -> list:
    """Play a script, turning 2 % of its Sensors into real-time advance() spans of 0..120 us."""
    rng = random.Random(seed)
    out: list = []
    for item in script:
        if item[0] == "sensors" and rng.random() < 0.02:
            out.append(target.advance(rng.uniform(0.0, 120.0), item[1]))
        else:
            out.extend(play(target, [item]))
    return out


def first_difference(a: list, b: list) -> str:
    """Where two recorded answer lists part (the first is the backend under test)."""
    for i, (x, y) in enumerate(zip(a, b)):
        if x != y:
            return f"item {i}: {x} != reference {y}"
    return f"lengths {len(a)} != {len(b)}"
