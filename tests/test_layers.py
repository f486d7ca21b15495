"""The house rules a grep can check: the bench names no firmware, and the constants the AN1017
compiled core restates by hand equal the Python model's."""

from __future__ import annotations

import re

from conftest import REPO_ROOT

from hilbench.protocol import Edge, Input, OutputMode, State
from hilbench.targets.an1017 import firmware, svm


def test_no_firmware_is_named_in_the_bench_or_the_cli() -> None:
    """Outside hilbench/targets, a firmware's name may appear only as the default target spec
    (hilbench.targets.registry.DEFAULT_TARGET), which neither the bench nor the CLI restates."""
    files = sorted((REPO_ROOT / "hilbench" / "bench").glob("*.py")) + [REPO_ROOT / "hilbench" / "cli.py"]
    found = [f"{path.relative_to(REPO_ROOT)}:{n}: {line.strip()}"
             for path in files for n, line in enumerate(path.read_text().splitlines(), 1)
             if re.search(r"an1017|f2812|\bfoc\b|dspic", line, re.IGNORECASE)]
    assert not found, "\n".join(found)


def _c_defines() -> dict[str, int]:
    text = (REPO_ROOT / "hilbench" / "targets" / "an1017" / "_core.c").read_text()
    out: dict[str, int] = {}
    for name, value in re.findall(r"^#define (\w+) (.+)$", text, re.MULTILINE):
        try:
            out[name] = int(eval(value, {}))  # noqa: S307 - integer literals and products from our own file
        except Exception:  # noqa: BLE001 - macros with arguments, includes
            continue
    return out


def _c_array(name: str) -> tuple[int, ...]:
    text = (REPO_ROOT / "hilbench" / "targets" / "an1017" / "_core.c").read_text()
    body = re.search(rf"{name}\[\d+\] = \{{([^}}]*)\}}", text)
    assert body is not None, name
    return tuple(int(x, 0) for x in body.group(1).replace(" ", "").split(","))


def test_the_compiled_cores_constants_equal_the_python_models() -> None:
    c = _c_defines()
    python = {
        "PWM_PERIOD_TCY": firmware.PWM_PERIOD_TCY, "TIMER1_PERIOD_TCY": firmware.TIMER1_PERIOD_TCY,
        "TMR3_PRESCALE": firmware.TMR3_PRESCALE, "BOOTSTRAP_TCY": firmware.BOOTSTRAP_TCY,
        "ADC_POSTSCALE_V11": firmware.ADC_POSTSCALE_V11, "MINPERIOD": firmware.MINPERIOD,
        "MAXPERIOD": firmware.MAXPERIOD, "MINPERIOD_DIVF": firmware.MINPERIOD_DIVF,
        "PHASE_OFFSET_DEFAULT": firmware.PHASE_OFFSET_CCW, "SECTOR_INVALID": firmware.SECTOR_INVALID,
        "FORCE_COMMUTATION_TICKS": firmware.FORCE_COMMUTATION_TICKS,
        "PHASEINC_NUMERATOR": firmware.PHASEINC_NUMERATOR,
        "STATE_STOPPED": int(State.STOPPED), "STATE_BOOTSTRAP": int(State.BOOTSTRAP),
        "STATE_RUNNING": int(State.RUNNING), "STATE_STALLED": int(State.STALLED),
        "MODE_OFF": int(OutputMode.OFF), "MODE_PWM": int(OutputMode.PWM), "MODE_LOW_SIDE": int(OutputMode.LOW_SIDE),
        "FAULT_NONE": firmware.FAULT_NONE, "FAULT_STALL": firmware.FAULT_STALL, "INPUT_S2": int(Input.S2),
        "PTPER": svm.PTPER, "TPWM": svm.TPWM, "VOLTS_LIMIT": svm.VOLTS_LIMIT, "SIXTY_DEG": svm.SIXTY_DEG,
        "EDGE_NONE": int(Edge.NONE),
    }
    assert {k: c.get(k) for k in python} == python
    assert _c_array("PHASE_VALUES") == firmware.PHASE_VALUES
    assert _c_array("SECTOR_TABLE") == firmware.SECTOR_TABLE
