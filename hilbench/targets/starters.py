"""Starting a build of a firmware as a process that speaks the protocol on a tty: sil:, simavr:, qemu:.

Each spec kind that runs a firmware build — `sil:` (built for this host), `simavr:` (an AVR in the
simavr simulator), `qemu:` (a Cortex-M in QEMU) — has a `FirmwareStarter`: it builds what it needs
(cached by content), starts the process and hands back a `Started` (the process and the tty the
firmware serves). There are two shapes: the process opens a tty the host made (the slave of a pty
pair, `serves_host_pty`), or it makes its own pty and names it in its ready line (simavr's UART
part). The launcher (hilbench.bench.launcher) connects a RemoteTarget to that tty and reaps the
process on every exit path.

A registered target lists its builds in `TargetProfile.starters` (kind -> starter), so `sil:an1017`
and `simavr:an1017` name them; `sil:PATH`, `simavr:PATH` (and `qemu:PATH`) name a build of a firmware
no hilbench module knows, which the bench then serves from its handshake alone (`PATH_STARTERS`).
"""

from __future__ import annotations

import os
import re
import select
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO, Callable, Mapping, Protocol

from hilbench.errors import ConfigError, LinkError
from hilbench.processes import reap, spawn

READY_TIMEOUT_S = 20.0
#: "ready PATH": the ready line of hilbench's host ports and of run_simavr
READY_LINE = re.compile(rb"^ready (\S+)")

REPO = Path(__file__).resolve().parent.parent.parent
RUN_SIMAVR_SOURCE = REPO / "firmware" / "an1017" / "ports" / "avr" / "run_simavr.c"
RUN_SIMAVR_HEADER = RUN_SIMAVR_SOURCE.with_name("uart_link.h")  # in the build's key: it changes the runner
SIMAVR_INCLUDE = Path("/usr/include/simavr")


@dataclass
class Started:
    """A firmware process serving `tty_path`; close() reaps it (and its log)."""

    process: subprocess.Popen[bytes]
    tty_path: str
    label: str
    log: IO[bytes] | None = None
    closers: list[Callable[[], None]] = field(default_factory=list)

    def exit_note(self) -> str:
        """How the process ended, with the last line it wrote, for error lines ("" while it runs)."""
        code = self.process.poll()
        if code is None:
            return ""
        tail = ""
        if self.log is not None:
            self.log.seek(0)
            lines = self.log.read().decode(errors="replace").strip().splitlines()
            tail = f": {lines[-1]}" if lines else ""
        return f" ({self.label} exited with code {code}{tail})"

    def close(self) -> int:
        code = reap(self.process)
        for stream in (self.process.stdout, self.process.stderr):
            if stream is not None:
                stream.close()
        if self.log is not None:
            self.log.close()
        for closer in self.closers:
            closer()
        return code


class FirmwareStarter(Protocol):
    """How one kind of firmware build is started (sil, simavr, qemu)."""

    kind: str
    #: True: start() gets the slave of a pty pair the host made; False: the process makes its own
    serves_host_pty: bool

    def start(self, options: object, host_tty: str | None) -> Started:
        """Build if needed, start the firmware, return once its tty is ready; LinkError/ConfigError else."""


def start_process(argv: list[str], label: str, *, ready: re.Pattern[bytes] = READY_LINE,
                  timeout_s: float = READY_TIMEOUT_S, stderr_ready: bool = False) -> Started:
    """Start argv and wait for its ready line (on stdout, or stderr with `stderr_ready`); the
    pattern's first group is the tty it serves. The process gets its own session (Ctrl-C reaches
    the bench, which reaps it), its other stream goes to a file that never fills up."""
    log = tempfile.TemporaryFile()
    try:
        process = spawn(argv, stdin=subprocess.DEVNULL,  # it dies with this process (hilbench.processes)
                        stdout=log if stderr_ready else subprocess.PIPE,
                        stderr=subprocess.PIPE if stderr_ready else log, start_new_session=True)
    except OSError as exc:
        log.close()
        raise LinkError(f"{label}: cannot start {argv[0]}: {exc.strerror}") from None
    started = Started(process, "", f"{label} (pid {process.pid})", log)
    stream = process.stderr if stderr_ready else process.stdout
    assert stream is not None
    try:
        started.tty_path = _wait_ready(stream, ready, timeout_s)
    except LinkError as exc:
        note = started.exit_note()
        started.close()
        raise LinkError(f"{label}: {exc}{note}") from None
    except BaseException:
        started.close()
        raise
    return started


def _wait_ready(stream: IO[bytes], ready: re.Pattern[bytes], timeout_s: float) -> str:
    """The tty named by the first line matching `ready` (other lines are skipped)."""
    deadline = time.monotonic() + timeout_s
    buffered = b""
    fd = stream.fileno()
    while True:
        while b"\n" in buffered:
            line, buffered = buffered.split(b"\n", 1)
            match = ready.search(line.strip())
            if match:
                return match.group(1).decode()
        left = deadline - time.monotonic()
        if left <= 0:
            raise LinkError(f"no ready line within {timeout_s:.0f} s")
        readable, _, _ = select.select([fd], [], [], left)
        chunk = os.read(fd, 4096) if readable else b""
        if readable and not chunk:
            raise LinkError("exited before it was ready")
        buffered += chunk


# -- the build cache -------------------------------------------------------------------------

def cache_root() -> Path:
    """Where builds are kept: $HILBENCH_CACHE_DIR, else $XDG_CACHE_HOME/hilbench, else ~/.cache/hilbench."""
    root = os.environ.get("HILBENCH_CACHE_DIR") or os.path.join(
        os.environ.get("XDG_CACHE_HOME") or os.path.expanduser("~/.cache"), "hilbench")
    return Path(root)


def cached_build(kind: str, name: str, inputs: list[Path], recipe: list[str],
                 build: Callable[[Path], None]) -> Path:
    """The output of `build(tmp_path)`, kept under cache_root()/kind as NAME-<digest of the inputs'
    contents and the recipe>; built now unless it exists. Atomic: a concurrent build never sees a
    half-written file."""
    import hashlib

    missing = [str(p) for p in inputs if not p.is_file()]
    if missing:
        raise ConfigError(f"{kind}:{name}: {missing[0]} not found (needs a source checkout)")
    digest = hashlib.sha256()
    for path in inputs:
        digest.update(path.name.encode() + b"\0" + path.read_bytes())
    digest.update("\0".join(recipe).encode())
    directory = cache_root() / kind
    directory.mkdir(parents=True, exist_ok=True)
    out = directory / f"{name}-{digest.hexdigest()[:16]}"
    if out.is_file():
        return out
    fd, tmp = tempfile.mkstemp(prefix=out.name + ".", dir=directory)
    os.close(fd)
    try:
        build(Path(tmp))
        os.replace(tmp, out)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return out


def run_build(kind: str, name: str, cmd: list[str], timeout_s: float = 300.0) -> None:
    """Run a compiler command; ConfigError with its first error line when it fails."""
    try:
        result = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout_s)
    except FileNotFoundError:
        raise ConfigError(f"{kind}:{name}: {cmd[0]} not found (install it to build the firmware)") from None
    if result.returncode != 0:
        lines = (result.stderr or result.stdout).strip().splitlines()
        first = next((line for line in lines if "error" in line), lines[0] if lines else "no output")
        raise ConfigError(f"{kind}:{name}: build failed: {first}")


def need_tool(kind: str, tool: str, package: str) -> str:
    path = shutil.which(tool)
    if path is None:
        raise ConfigError(f"{kind}: {tool} not found on PATH (Debian: apt-get install {package})")
    return path


# -- sil: a host build ------------------------------------------------------------------------

@dataclass(frozen=True)
class HostExecutableStarter:
    """A firmware built for this host with a hilbench host port: `EXE [ARGS] --ready TTY` opens the
    host's pty slave and prints "ready TTY". `build` gives the executable for the options."""

    build: Callable[[object], Path]
    args: Callable[[object], list[str]] = field(default=lambda options: [])
    name: str = "firmware"
    kind: str = "sil"
    serves_host_pty: bool = True

    def start(self, options: object, host_tty: str | None) -> Started:
        assert host_tty is not None
        exe = self.build(options)
        return start_process([str(exe), *self.args(options), "--ready", host_tty], f"sil:{self.name}")


def build_folder(kind: str, folder: Path, goal: str, pattern: str) -> Path:
    """A firmware folder with a Makefile on firmware/runtime/firmware.mk: `make -C FOLDER GOAL` (make
    decides what is stale), then the one file of ``pattern`` in its build/."""
    make = need_tool(kind, "make", "make")
    run_build(kind, str(folder), [make, "-s", "-C", str(folder), goal])
    found = sorted((folder / "build").glob(pattern))
    if len(found) != 1:
        raise ConfigError(f"{kind}:{folder}: `make {goal}` left {len(found)} files {pattern} in {folder / 'build'} "
                          "(a folder on firmware/runtime/firmware.mk leaves one)")
    return found[0]


def sil_path_starter(path: str) -> HostExecutableStarter:
    """`sil:PATH`: an executable built with a hilbench host port (firmware/runtime/ports/host), or a
    firmware folder whose Makefile includes firmware/runtime/firmware.mk (`make sil` builds it)."""
    where = Path(path).expanduser()

    def build(options: object) -> Path:
        if where.is_dir() and (where / "Makefile").is_file():
            return build_folder("sil", where, "sil", "*_sil")
        if not where.is_file() or not os.access(where, os.X_OK):
            raise ConfigError(f"sil:{path}: no executable there and no firmware folder with a Makefile (build the "
                              "firmware's host port first, e.g. make -C firmware/template)")
        return where

    return HostExecutableStarter(build, name=str(path))


# -- simavr: an AVR build in the simulator ----------------------------------------------------

def build_run_simavr() -> Path:
    """The simavr runner (run_simavr.c: the ELF on a simulated ATmega with USART0 on a pty)."""
    kind = "simavr"
    gcc = need_tool(kind, "gcc", "gcc")
    if not (SIMAVR_INCLUDE / "sim_avr.h").is_file():
        raise ConfigError(f"{kind}: simavr's headers not found in {SIMAVR_INCLUDE} (Debian: apt-get install libsimavr-dev)")
    cmd = [gcc, "-std=gnu99", "-O2", "-Wall", "-Wextra", "-Werror", f"-I{SIMAVR_INCLUDE}",
           f"-I{SIMAVR_INCLUDE / 'parts'}", str(RUN_SIMAVR_SOURCE)]
    libs = ["-lsimavrparts", "-lsimavr", "-lpthread", "-lutil"]
    return cached_build(kind, "run_simavr", [RUN_SIMAVR_SOURCE, RUN_SIMAVR_HEADER], cmd + libs,
                        lambda out: run_build(kind, "run_simavr", [*cmd, "-o", str(out), *libs]))


@dataclass(frozen=True)
class SimavrStarter:
    """An AVR ELF in simavr (`run_simavr ELF MCU F_CPU`), its USART0 on a pty it makes."""

    build: Callable[[object], Path]
    mcu: str = "atmega328p"
    f_cpu_hz: int = 16_000_000
    name: str = "firmware"
    kind: str = "simavr"
    serves_host_pty: bool = False

    def start(self, options: object, host_tty: str | None) -> Started:
        elf = self.build(options)
        runner = build_run_simavr()
        return start_process([str(runner), str(elf), self.mcu, str(self.f_cpu_hz)], f"simavr:{self.name}")


def simavr_path_starter(path: str) -> SimavrStarter:
    """`simavr:PATH`: an ATmega328P ELF built with a hilbench AVR port (16 MHz, USART0 at 250 kbaud), or
    a firmware folder on firmware/runtime/firmware.mk (`make avr` builds it)."""
    where = Path(path).expanduser()

    def build(options: object) -> Path:
        if where.is_dir() and (where / "Makefile").is_file():
            return build_folder("simavr", where, "avr", "*_avr.elf")
        if not where.is_file():
            raise ConfigError(f"simavr:{path}: no ELF there and no firmware folder with a Makefile (build the "
                              "firmware's AVR port first, e.g. make -C firmware/template avr)")
        return where

    return SimavrStarter(build, name=str(path))


def qemu_path_starter(path: str) -> FirmwareStarter:
    """`qemu:PATH`: an ELF built with hilbench's Cortex-M4 port (hilbench.targets.qemu)."""
    from hilbench.targets.qemu import qemu_path_starter as make

    return make(path)


#: `KIND:PATH` specs: a build of a firmware no hilbench module knows
PATH_STARTERS: dict[str, Callable[[str], FirmwareStarter]] = {
    "sil": sil_path_starter,
    "simavr": simavr_path_starter,
    "qemu": qemu_path_starter,
}

#: the spec kinds that start a firmware build
FIRMWARE_KINDS = ("sil", "simavr", "qemu")


def starter_for(kind: str, starters: Mapping[str, FirmwareStarter], target: str) -> FirmwareStarter:
    """The starter of `kind` among a profile's, or a ConfigError naming the kinds it has."""
    starter = starters.get(kind)
    if starter is None:
        have = ", ".join(f"{k}:{target}" for k in sorted(starters)) or "none"
        raise ConfigError(f"target {kind}:{target}: {target} has no {kind} build (its firmware builds: {have}; "
                          "or use emulator: / inprocess:)")
    return starter


__all__ = [
    "FIRMWARE_KINDS",
    "FirmwareStarter",
    "HostExecutableStarter",
    "PATH_STARTERS",
    "SimavrStarter",
    "Started",
    "build_folder",
    "build_run_simavr",
    "cache_root",
    "cached_build",
    "need_tool",
    "run_build",
    "sil_path_starter",
    "simavr_path_starter",
    "start_process",
    "starter_for",
]
