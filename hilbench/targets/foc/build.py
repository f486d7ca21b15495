"""How the FOC firmware (firmware/foc) is built for a given `[target]` table, and the builds that
run it as a process: `sil:foc` (this host, on a pty) and `qemu:foc` (a Cortex-M4 in QEMU).

The in-process core takes the settings at run time (`firmware_config`); every other build (SIL,
the simulated MCUs, a board) compiles them in: firmware/foc/foc_config.h holds the servo build's
values, and `config_defines(options)` overrides each one that differs, so any `[target]` table
builds the same firmware everywhere. The builds link the firmware with the runtime
(firmware/runtime) and the protocol library (firmware_protocol) and are cached by content.
"""

from __future__ import annotations

import hashlib
import os
import select
import shutil
import subprocess
import tempfile
from pathlib import Path
from typing import TYPE_CHECKING

from hilbench.errors import ConfigError, LinkError
from hilbench.processes import reap
from hilbench.targets.foc.firmware import FocOptions, firmware_config

if TYPE_CHECKING:
    from hilbench.targets.qemu import M4Build

REPO = Path(__file__).resolve().parents[3]
FIRMWARE_DIR = REPO / "firmware" / "foc"
RUNTIME_DIR = REPO / "firmware" / "runtime"
PROTOCOL_DIR = REPO / "firmware_protocol"
STRICT_FLAGS = ("-std=c99", "-pedantic", "-Wall", "-Wextra", "-Wconversion", "-Werror", "-O2")
READY_TIMEOUT_S = 10.0
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
    """The host build: the firmware, its runtime binding and host port, the runtime, the protocol."""
    return (*SOURCES, FIRMWARE_DIR / "foc_hrt.c", FIRMWARE_DIR / "ports" / "host" / "main.c",
            RUNTIME_DIR / "hrt.c", RUNTIME_DIR / "hrt_link.c", PROTOCOL_DIR / "hbp.c", PROTOCOL_DIR / "hbp_messages.c")


def _headers() -> list[Path]:
    return sorted(p for d in (FIRMWARE_DIR, RUNTIME_DIR, PROTOCOL_DIR) if d.is_dir() for p in d.glob("*.h"))


def build_sil(options: FocOptions = FocOptions(), out_dir: Path | None = None) -> Path:
    """The SIL executable of this `[target]` table, compiled now unless an identical build exists."""
    from hilbench.targets.sil import cache_dir

    compiler = shutil.which("gcc") or shutil.which("cc")
    if compiler is None:
        raise ConfigError("sil:foc: no C compiler (gcc) on PATH to build the firmware")
    sources = sil_sources()
    missing = [str(p) for p in sources if not p.is_file()]
    if missing:
        raise ConfigError(f"sil:foc: firmware source {missing[0]} not found (needs a source checkout)")
    flags = (*STRICT_FLAGS, *config_defines(options))
    digest = hashlib.sha256(" ".join((*flags, compiler)).encode())
    for path in (*sources, *_headers()):
        digest.update(str(path.relative_to(REPO)).encode() + b"\0" + path.read_bytes())
    directory = out_dir or cache_dir()
    directory.mkdir(parents=True, exist_ok=True)
    exe = directory / f"foc_sil-{digest.hexdigest()[:16]}"
    if exe.is_file():
        return exe
    fd, tmp = tempfile.mkstemp(prefix=exe.name + ".", dir=directory)
    os.close(fd)
    includes = [f"-I{d}" for d in (FIRMWARE_DIR, RUNTIME_DIR, PROTOCOL_DIR)]
    try:
        done = subprocess.run([compiler, *flags, *includes, *(str(s) for s in sources), "-o", tmp],
                              capture_output=True, text=True, timeout=180)
        if done.returncode != 0:
            lines = (done.stderr or done.stdout).strip().splitlines() or ["no output"]
            raise ConfigError(f"sil:foc: build failed: {lines[0]}")
        os.replace(tmp, exe)  # atomic: a concurrent build never sees a half-written binary
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return exe


def start_sil(settings: object, tty_path: str) -> "subprocess.Popen[bytes]":
    """The FOC firmware built for this host (first if needed), serving tty_path once this returns."""
    exe = build_sil(_options(settings))
    with tempfile.TemporaryFile() as log:  # its complaints, if it fails to start (a file never blocks it)
        process = subprocess.Popen([str(exe), "--ready", tty_path], stdin=subprocess.DEVNULL,
                                   stdout=subprocess.PIPE, stderr=log)
        assert process.stdout is not None
        ready, _, _ = select.select([process.stdout], [], [], READY_TIMEOUT_S)
        line = process.stdout.readline() if ready else b""
        if not line.startswith(b"ready"):
            reap(process)
            process.stdout.close()
            log.seek(0)
            err = log.read().decode(errors="replace").strip()
            raise LinkError(f"sil:foc on {tty_path}: firmware did not start: {err or 'no ready line'}")
    return process


def qemu_build(settings: object) -> "M4Build":
    """The FOC firmware for the Cortex-M4 in QEMU (`qemu:foc`): make goal, settings, sources."""
    from hilbench.targets.qemu import M4Build

    return M4Build("foc", "foc_m4.elf", ("DEFS=" + " ".join(config_defines(_options(settings))),),
                   (FIRMWARE_DIR, RUNTIME_DIR, PROTOCOL_DIR))


__all__ = ["FIRMWARE_DIR", "HEADERS", "SOURCES", "build_sil", "config_defines", "qemu_build", "sil_sources",
           "start_sil"]
