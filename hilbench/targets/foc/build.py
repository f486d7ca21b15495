"""How the FOC firmware (firmware/foc) is built for a given `[target]` table, and the builds that
run it as a process: `sil:foc` (this host), `simavr:foc` (an ATmega1284P in simavr) and
`qemu:foc` (a Cortex-M4 in QEMU); the profile's starters (hilbench.targets.starters) run them.

The in-process core takes the settings at run time (`firmware_config`); every other build (SIL,
the simulated MCUs, a board) compiles them in: firmware/foc/foc_config.h holds the servo build's
values, and `config_defines(options)` overrides each one that differs, so any `[target]` table
builds the same firmware everywhere. The builds link the firmware with the runtime
(firmware/runtime) and the protocol library (firmware_protocol) and are cached by content.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from hilbench.targets.foc.firmware import FocOptions, firmware_config

if TYPE_CHECKING:
    from hilbench.targets.qemu import M4Build

REPO = Path(__file__).resolve().parents[3]
FIRMWARE_DIR = REPO / "firmware" / "foc"
RUNTIME_DIR = REPO / "firmware" / "runtime"
PROTOCOL_DIR = REPO / "firmware_protocol"
STRICT_FLAGS = ("-std=c99", "-pedantic", "-Wall", "-Wextra", "-Wconversion", "-Werror", "-O2")
#: the firmware's portable sources (every build compiles these three)
SOURCES = (FIRMWARE_DIR / "foc.c", FIRMWARE_DIR / "foc_blocks.c", FIRMWARE_DIR / "foc_sin_table.c")
HEADERS = (FIRMWARE_DIR / "foc.h", FIRMWARE_DIR / "foc_blocks.h", FIRMWARE_DIR / "foc_config.h",
           FIRMWARE_DIR / "iq24.h")


def _literal(value: int) -> str:
    """A C constant of a 32-bit long (parenthesised when negative, so it survives any context)."""
    if value == -(1 << 31):
        return "(-2147483647L-1L)"
    return f"({value}L)" if value < 0 else f"{value}L"


def config_defines(options: FocOptions = FocOptions()) -> tuple[str, ...]:
    """-DFOC_CFG_* for every setting that differs from the servo build (none for FocOptions())."""
    default = firmware_config(FocOptions())
    values = firmware_config(options)
    return tuple(f"-DFOC_CFG_{key.upper()}={_literal(value)}" for key, value in values.items()
                 if value != default[key])


def _options(settings: object) -> FocOptions:
    return settings if isinstance(settings, FocOptions) else FocOptions()


def sil_sources() -> tuple[Path, ...]:
    """The host build: the firmware, its runtime binding, the runtime's shared host port, the runtime,
    the protocol."""
    return (*SOURCES, FIRMWARE_DIR / "foc_hrt.c", RUNTIME_DIR / "ports" / "host" / "hrt_host.c",
            RUNTIME_DIR / "hrt.c", RUNTIME_DIR / "hrt_link.c", PROTOCOL_DIR / "hbp.c", PROTOCOL_DIR / "hbp_messages.c")


def _headers() -> list[Path]:
    return sorted(p for d in (FIRMWARE_DIR, RUNTIME_DIR, RUNTIME_DIR / "ports" / "avr", PROTOCOL_DIR) if d.is_dir()
                  for p in d.glob("*.h"))


def build_sil(options: FocOptions = FocOptions()) -> Path:
    """The SIL executable of this `[target]` table (gcc, the strict flags), cached by content."""
    from hilbench.targets.starters import cached_build, need_tool, run_build

    gcc = need_tool("sil", "gcc", "gcc")
    sources = list(sil_sources())
    cmd = [gcc, *STRICT_FLAGS, *config_defines(options), *(f"-I{d}" for d in (FIRMWARE_DIR, RUNTIME_DIR, PROTOCOL_DIR)),
           *(str(s) for s in sources)]
    return cached_build("sil", "foc_sil", [*sources, *_headers()], cmd,
                        lambda out: run_build("sil", "foc", [*cmd, "-o", str(out)]))


def build_avr(settings: object) -> Path:
    """The ATmega1284P ELF of this `[target]` table (the runtime's AVR port, firmware/runtime/ports/avr,
    with avr-gcc; the ATmega1284P for the 32 KB IQ24 sine table), cached."""
    from hilbench.targets.starters import cached_build, need_tool, run_build

    avr_gcc = need_tool("simavr", "avr-gcc", "gcc-avr avr-libc")
    sources = [RUNTIME_DIR / "ports" / "avr" / "hrt_avr.c", *SOURCES, FIRMWARE_DIR / "foc_hrt.c", RUNTIME_DIR / "hrt.c",
               RUNTIME_DIR / "hrt_link.c", PROTOCOL_DIR / "hbp.c", PROTOCOL_DIR / "hbp_messages.c"]
    # the runtime's own AVR port, its USART at 1 000 000 baud (UBRR0 = 1 with U2X0 at 16 MHz)
    cmd = [avr_gcc, "-mmcu=atmega1284p", "-DF_CPU=16000000UL", "-DHRT_AVR_UBRR=1u", "-Os", *STRICT_FLAGS[:-1],
           *config_defines(_options(settings)), *(f"-I{d}" for d in (FIRMWARE_DIR, RUNTIME_DIR, PROTOCOL_DIR)),
           *(str(s) for s in sources)]
    return cached_build("simavr", "foc_avr", [*sources, *_headers()], cmd,
                        lambda out: run_build("simavr", "foc", [*cmd, "-o", str(out)]))


def qemu_build(settings: object) -> "M4Build":
    """The FOC firmware for the Cortex-M4 in QEMU (`qemu:foc`): make goal, settings, sources."""
    import shlex

    from hilbench.targets.qemu import M4Build

    # make hands DEFS to the shell: each define quoted, or a negative value's "(" is a syntax error
    defines = " ".join(shlex.quote(d) for d in config_defines(_options(settings)))
    return M4Build("foc", "foc_m4.elf", ("DEFS=" + defines,), (FIRMWARE_DIR, RUNTIME_DIR, PROTOCOL_DIR))


__all__ = ["FIRMWARE_DIR", "HEADERS", "SOURCES", "build_avr", "build_sil", "config_defines", "qemu_build",
           "sil_sources"]
