"""The AN1017 firmware in the loop on the host (SIL): build firmware/an1017 with gcc, run it on a pty.

The C firmware (firmware/an1017/: its ISR bodies and state, and ports/host/an1017_host.c on the
runtime's shared host port, on the runtime firmware/runtime/ and the firmware_protocol/ C library) is the very source that runs on the
dsPIC30F2010 and in the AVR simulator. `build_sil()` compiles it once into a cache directory keyed by the sources, flags and
compiler; `start_sil(tty_path)` starts it serving that tty and returns when it listens;
`SilTarget` opens a pty link, starts the process on it and hands back a RemoteTarget (what the
bench's `sil:an1017` spec needs). Every process started here is reaped by its owner's close().

From a shell, `python -m hilbench.targets.sil [--variant v11]` builds it and runs it on a pty of
its own, like a board on a serial port: it prints `ready /dev/pts/N` and serves any number of
sessions (`hilbench run --target /dev/pts/N`) until Ctrl-C.
"""

from __future__ import annotations

import hashlib
import os
import select
import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Literal

from hilbench.processes import reap, spawn
from hilbench.errors import ConfigError, LinkError

if TYPE_CHECKING:
    from hilbench.link.link import Link
    from hilbench.targets.remote import RemoteTarget

REPO = Path(__file__).resolve().parent.parent.parent
FIRMWARE_DIR = REPO / "firmware" / "an1017"
RUNTIME_DIR = REPO / "firmware" / "runtime"
PROTOCOL_DIR = REPO / "firmware_protocol"
#: the runtime (scheduler, real-time glue, the protocol's side) and the wire library, under every firmware
RUNTIME_SOURCES = (RUNTIME_DIR / "hrt.c", RUNTIME_DIR / "hrt_link.c", PROTOCOL_DIR / "hbp.c")
RUNTIME_HEADERS = (RUNTIME_DIR / "hrt.h", RUNTIME_DIR / "hrt_link.h", PROTOCOL_DIR / "hbp.h",
                   PROTOCOL_DIR / "hbp_messages.h")
SOURCES = (FIRMWARE_DIR / "an1017.c", FIRMWARE_DIR / "ports" / "host" / "an1017_host.c",
           RUNTIME_DIR / "ports" / "host" / "hrt_host.c", *RUNTIME_SOURCES)
HEADERS = (FIRMWARE_DIR / "an1017.h", FIRMWARE_DIR / "hrt_config.h", FIRMWARE_DIR / "q15.h", *RUNTIME_HEADERS)
# the strict flags every firmware build uses, and the AN1017 profile's protocol capacities
CFLAGS = ("-std=c99", "-pedantic", "-Wall", "-Wextra", "-Wconversion", "-Werror", "-O2",
          "-DHBP_MAX_ADC=3u", "-DHBP_MAX_TELEMETRY=3u", "-DHBP_MAX_EDGES=3u")
READY_TIMEOUT_S = 10.0
Variant = Literal["seed", "v11"]


def cache_dir() -> Path:
    """Where built SIL binaries are kept: $HILBENCH_CACHE_DIR, else $XDG_CACHE_HOME/hilbench, else ~/.cache/hilbench."""
    root = os.environ.get("HILBENCH_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "hilbench")
    return Path(root) / "sil"


def motor_defines(pole_pairs: int = 5, max_speed_rpm: int = 6000) -> tuple[str, ...]:
    """The build-time defines of the motor the firmware is built for (docs/board.md); none for the note's."""
    if (pole_pairs, max_speed_rpm) == (5, 6000):
        return ()
    return (f"-DAN1017_POLE_PAIRS={int(pole_pairs)}UL", f"-DAN1017_MAX_SPEED_RPM={int(max_speed_rpm)}UL")


def build_sil(out_dir: Path | None = None, *, cc: str | None = None, defines: tuple[str, ...] = ()) -> Path:
    """The SIL executable, compiled now unless an identical build (same sources, flags, defines, compiler) exists."""
    compiler = cc or shutil.which("gcc") or shutil.which("cc")
    if compiler is None:
        raise ConfigError("sil:an1017: no C compiler (gcc) on PATH to build the firmware")
    missing = [str(p) for p in SOURCES + HEADERS if not p.is_file()]
    if missing:
        raise ConfigError(f"sil:an1017: firmware source {missing[0]} not found (needs a source checkout)")
    digest = hashlib.sha256()
    for path in SOURCES + HEADERS:
        digest.update(path.name.encode() + b"\0" + path.read_bytes())
    digest.update(" ".join(CFLAGS + defines).encode() + b"\0" + compiler.encode())
    directory = out_dir or cache_dir()
    directory.mkdir(parents=True, exist_ok=True)
    exe = directory / f"an1017_sil-{digest.hexdigest()[:16]}"
    if exe.is_file():
        return exe
    fd, tmp = tempfile.mkstemp(prefix=exe.name + ".", dir=directory)
    os.close(fd)
    cmd = [compiler, *CFLAGS, *defines, f"-I{FIRMWARE_DIR}", f"-I{RUNTIME_DIR}", f"-I{PROTOCOL_DIR}",
           *(str(s) for s in SOURCES), "-o", tmp]
    try:
        result = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
        if result.returncode != 0:
            raise ConfigError(f"sil:an1017: build failed: {(result.stderr or result.stdout).strip().splitlines()[0]}")
        os.replace(tmp, exe)  # atomic: a concurrent build never sees a half-written binary
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return exe


def start_sil(tty_path: str, variant: Variant = "seed", *, exe: Path | None = None,
              defines: tuple[str, ...] = ()) -> subprocess.Popen[bytes]:
    """Start the SIL firmware (built with `defines`, see `motor_defines`) serving tty_path; returns
    once it has opened the tty (its "ready" line)."""
    if variant not in ("seed", "v11"):
        raise ConfigError(f"sil:an1017 variant {variant!r}: expected 'seed' or 'v11'")
    program = exe or build_sil(defines=defines)
    process = spawn([str(program), "--variant", variant, "--ready", tty_path],  # dies with us (hilbench.processes)
                    stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    assert process.stdout is not None
    ready, _, _ = select.select([process.stdout], [], [], READY_TIMEOUT_S)
    line = process.stdout.readline() if ready else b""
    if not line.startswith(b"ready"):
        reap(process)
        err = process.stderr.read().decode(errors="replace").strip() if process.stderr else ""
        _close_pipes(process)
        raise LinkError(f"sil:an1017 on {tty_path}: firmware did not start: {err or 'no ready line'}")
    return process


def _close_pipes(process: subprocess.Popen[bytes]) -> None:
    for stream in (process.stdout, process.stderr):
        if stream is not None:
            stream.close()


def stop_sil(process: subprocess.Popen[bytes], timeout_s: float = 3.0) -> int:
    """Terminate the SIL process (it also exits by itself when its tty hangs up) and reap it."""
    code = reap(process, timeout_s)
    _close_pipes(process)
    return code


@dataclass
class SilTarget:
    """A running SIL firmware on a fresh pty, with the RemoteTarget that talks to it. close() reaps it."""

    target: RemoteTarget
    link: Link
    process: subprocess.Popen[bytes]
    label: str

    @classmethod
    def open(cls, variant: Variant = "seed", *, timeout_s: float = 2.0, exe: Path | None = None) -> "SilTarget":
        from hilbench.link import open_link
        from hilbench.targets.remote import RemoteTarget

        exe = exe or build_sil()  # before the pty exists: a build error leaves nothing to clean up
        link = open_link("pty", timeout_s=timeout_s)
        try:
            process = start_sil(link.peer_path, variant, exe=exe)
        except BaseException:
            link.close()
            raise
        label = f"sil:an1017 on {link.peer_path} (pid {process.pid})"
        return cls(RemoteTarget(link, timeout_s=timeout_s), link, process, label)

    def close(self) -> int:
        try:
            self.link.close()  # the firmware sees the hang-up and exits
        finally:
            code = stop_sil(self.process)
        return code

    def __enter__(self) -> "SilTarget":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def main(argv: list[str] | None = None) -> None:
    """Build the SIL firmware and become it, serving its own pty (docs/board.md, "Without a board")."""
    import argparse

    parser = argparse.ArgumentParser(prog="python -m hilbench.targets.sil", description=main.__doc__)
    parser.add_argument("--variant", choices=("seed", "v11"), default="seed")
    parser.add_argument("--build-only", action="store_true", help="print the executable's path and exit")
    args = parser.parse_args(argv)
    exe = build_sil()
    if args.build_only:
        print(exe)
        return
    os.execv(exe, [str(exe), "--variant", args.variant, "--pty"])


AVR_DIR = FIRMWARE_DIR / "ports" / "avr"
#: the AVR port's build (its Makefile's flags): an ATmega328P at 16 MHz, USART0 at 250 kbaud
AVR_MCU = "atmega328p"
AVR_F_CPU_HZ = 16_000_000
AVR_CFLAGS = (f"-mmcu={AVR_MCU}", f"-DF_CPU={AVR_F_CPU_HZ}UL", "-Os", "-std=c99", "-pedantic", "-Wall", "-Wextra",
              "-Wconversion", "-Werror", "-DHBP_MAX_ADC=3u", "-DHBP_MAX_TELEMETRY=3u", "-DHBP_MAX_EDGES=3u")


def build_avr(variant: Variant = "seed", defines: tuple[str, ...] = ()) -> Path:
    """The AVR port's ELF (firmware/an1017/ports/avr with the runtime), compiled with avr-gcc into the
    build cache unless an identical build exists (the same sources, flags and defines)."""
    from hilbench.targets.starters import cached_build, need_tool, run_build

    avr_gcc = need_tool("simavr:an1017", "avr-gcc", "gcc-avr avr-libc")
    sources = (AVR_DIR / "main.c", RUNTIME_DIR / "ports" / "avr" / "hrt_avr.c", FIRMWARE_DIR / "an1017.c",
               *RUNTIME_SOURCES)
    variant_define = "-DAN1017_VARIANT=" + ("AN1017_VARIANT_V11" if variant == "v11" else "AN1017_VARIANT_SEED")
    cmd = [avr_gcc, *AVR_CFLAGS, variant_define, *defines, f"-I{FIRMWARE_DIR}", f"-I{RUNTIME_DIR}",
           f"-I{PROTOCOL_DIR}", *(str(s) for s in sources)]
    return cached_build("simavr", f"an1017_{variant}", [*sources, *HEADERS, RUNTIME_DIR / "ports" / "avr" / "hrt_avr.h"], cmd,
                        lambda out: run_build("simavr", "an1017", [*cmd, "-o", str(out)]))


__all__ = ["AVR_F_CPU_HZ", "AVR_MCU", "SilTarget", "build_avr", "build_sil", "cache_dir", "main", "start_sil",
           "stop_sil"]


if __name__ == "__main__":
    main()
