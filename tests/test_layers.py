"""The house rules a grep can check: the bench names no firmware, the AN1017 board firmware's
constants and tables equal the Python model's, and the in-process core restates none of them."""

from __future__ import annotations

import re

from conftest import REPO_ROOT

from hilbench.protocol import Input, OutputMode, State
from hilbench.targets.an1017 import firmware, svm


def test_no_firmware_is_named_in_the_bench_or_the_cli() -> None:
    """Outside hilbench/targets, a firmware's name may appear only as the default target spec
    (hilbench.targets.registry.DEFAULT_TARGET), which neither the bench nor the CLI restates."""
    files = sorted((REPO_ROOT / "hilbench" / "bench").glob("*.py")) + [REPO_ROOT / "hilbench" / "cli.py"]
    found = [f"{path.relative_to(REPO_ROOT)}:{n}: {line.strip()}"
             for path in files for n, line in enumerate(path.read_text().splitlines(), 1)
             if re.search(r"an1017|f2812|\bfoc\b|dspic", line, re.IGNORECASE)]
    assert not found, "\n".join(found)


FIRMWARE_DIR = REPO_ROOT / "firmware" / "an1017"


def _c_defines(path) -> dict[str, int]:
    """#define NAME <integer expression> of a C file, with the u/UL suffixes and comments dropped."""
    out: dict[str, int] = {}
    for name, value in re.findall(r"^#define (\w+) (.+)$", path.read_text(), re.MULTILINE):
        value = re.sub(r"/\*.*?\*/", "", value)
        value = re.sub(r"\b(0x[0-9A-Fa-f]+|\d+)[uUlL]+\b", r"\1", value).strip()
        try:
            out[name] = int(eval(value, {}))  # noqa: S307 - integer literals and products from our own file
        except Exception:  # noqa: BLE001 - macros with arguments, casts, includes
            continue
    return out


def _c_array(path, name: str) -> tuple[int, ...]:
    body = re.search(rf"{name}\[\d+\][^=]*= \{{([^}}]*)\}}", path.read_text())
    assert body is not None, name
    return tuple(int(x.rstrip("uU"), 0) for x in re.sub(r"\s", "", body.group(1)).split(","))


def test_the_board_firmwares_constants_equal_the_python_models() -> None:
    """firmware/an1017 is the one C source (board, SIL, in-process core): its constants and tables
    are the Python reference's."""
    h = _c_defines(FIRMWARE_DIR / "an1017.h")
    c = _c_defines(FIRMWARE_DIR / "an1017.c")
    board = {
        "PWM_PERIOD_TCY": h["AN1017_PWM_PERIOD_TCY"], "TIMER1_PERIOD_TCY": h["AN1017_TIMER1_PERIOD_TCY"],
        "BOOTSTRAP_TCY": h["AN1017_BOOTSTRAP_TCY"], "ADC_POSTSCALE_V11": c["ADC_POSTSCALE_MASK"] + 1,
        "PHASE_OFFSET": h["AN1017_PHASE_OFFSET"], "SECTOR_INVALID": h["AN1017_SECTOR_INVALID"],
        "FORCE_COMMUTATION_TICKS": c["FORCE_COMMUTATION_TICKS"], "PHASEINC_NUMERATOR": c["PHASEINC_NUMERATOR"],
        "STATES": tuple(h[f"AN1017_STATE_{n}"] for n in ("STOPPED", "BOOTSTRAP", "RUNNING", "STALLED", "FAULT")),
        "MODES": tuple(h[f"AN1017_MODE_{n}"] for n in ("OFF", "PWM", "LOW_SIDE")),
        "FAULTS": tuple(h[f"AN1017_FAULT_{n}"] for n in ("NONE", "WATCHDOG", "STALL", "OVERCURRENT")),
        "INPUTS": (h["AN1017_INPUT_S2"], h["AN1017_INPUT_FAULT"]),
        "PTPER": h["AN1017_PTPER"], "TPWM": h["AN1017_TPWM"], "VOLTS_LIMIT": h["AN1017_VOLTS_LIMIT"],
        "SIXTY_DEG": c["SIXTY_DEG"], "GAINS": (c["KP_DEFAULT"], c["KI_DEFAULT"], c["KD_DEFAULT"]),
        "PHASE_VALUES": _c_array(FIRMWARE_DIR / "an1017.c", "phase_values"),
        "SECTOR_TABLE": _c_array(FIRMWARE_DIR / "an1017.c", "sector_table"),
        "SINE_TABLE": _c_array(FIRMWARE_DIR / "an1017.c", "sine_table"),
    }
    python = {
        "PWM_PERIOD_TCY": firmware.PWM_PERIOD_TCY, "TIMER1_PERIOD_TCY": firmware.TIMER1_PERIOD_TCY,
        "BOOTSTRAP_TCY": firmware.BOOTSTRAP_TCY, "ADC_POSTSCALE_V11": firmware.ADC_POSTSCALE_V11,
        "PHASE_OFFSET": firmware.PHASE_OFFSET_CCW, "SECTOR_INVALID": firmware.SECTOR_INVALID,
        "FORCE_COMMUTATION_TICKS": firmware.FORCE_COMMUTATION_TICKS,
        "PHASEINC_NUMERATOR": firmware.PHASEINC_NUMERATOR,
        "STATES": (int(State.STOPPED), int(State.BOOTSTRAP), int(State.RUNNING), int(State.STALLED),
                   int(State.FAULT)),
        "MODES": (int(OutputMode.OFF), int(OutputMode.PWM), int(OutputMode.LOW_SIDE)),
        "FAULTS": (firmware.FAULT_NONE, firmware.FAULT_WATCHDOG, firmware.FAULT_STALL, firmware.FAULT_OVERCURRENT),
        "INPUTS": (int(Input.S2), int(Input.FAULT)),
        "PTPER": svm.PTPER, "TPWM": svm.TPWM, "VOLTS_LIMIT": svm.VOLTS_LIMIT, "SIXTY_DEG": svm.SIXTY_DEG,
        "GAINS": (firmware.KP_DEFAULT_Q15, firmware.KI_DEFAULT_Q15, firmware.KD_DEFAULT_Q15),
        "PHASE_VALUES": firmware.PHASE_VALUES,
        "SECTOR_TABLE": tuple(x & 0xFFFF for x in firmware.SECTOR_TABLE),
        "SINE_TABLE": svm.SINE_TABLE,
    }
    assert board == python
    assert (h["AN1017_POLE_PAIRS"], h["AN1017_MAX_SPEED_RPM"]) == (firmware.POLE_PAIRS_DEFAULT,
                                                                   firmware.MAX_SPEED_RPM_DEFAULT)


def test_the_in_process_core_restates_no_firmware() -> None:
    """hilbench/targets/an1017/_core.c is glue around an1017.c: no tables, no firmware constants."""
    glue = (REPO_ROOT / "hilbench" / "targets" / "an1017" / "_core.c").read_text()
    assert '#include "an1017.h"' in glue
    defines = _c_defines(REPO_ROOT / "hilbench" / "targets" / "an1017" / "_core.c")
    assert set(defines) <= {"SPAN_MAX_TCY", "MAX_SPAN_EDGES"}
    assert not re.search(r"static const \w+ \w+\[", glue), "a table in the glue"
