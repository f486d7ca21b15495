"""Firmware on a simulated Cortex-M4: built with arm-none-eabi-gcc, run in QEMU's mps2-an386 machine.

`qemu:NAME` builds the target's firmware for the Arm MPS2 AN386 image (firmware/runtime/ports/cortex_m4:
startup code, memory map, UART0 and clock of our own, the firmware's portable C source) with
`make`, and starts `qemu-system-arm -M mps2-an386 -nographic -kernel FW.elf -serial TTY -monitor
none` with the board's UART0 on the slave of a pty pair the bench made (as `sil:` does). Builds are
cached by the content of their sources, the make variables and the compiler.

Why not `-serial pty` for the bench: QEMU's own pty notices a newly opened slave only at its
once-a-second poll, so the first handshake would wait up to a second and could time out. By hand,
`python -m hilbench.targets.qemu NAME` runs it that way (QEMU prints `char device redirected to
/dev/pts/N`): connect to that path like a board.

QEMU dies with its parent: it runs in a session of its own (a Ctrl-C in the terminal reaches the
bench, which reaps it) and with PR_SET_PDEATHSIG = SIGKILL (a parent killed outright takes it along).
"""

from __future__ import annotations

import hashlib
import os
import shutil
import subprocess
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Callable

from hilbench.errors import ConfigError, LinkError
from hilbench.processes import reap, spawn
from hilbench.targets.starters import Started, cache_root

REPO = Path(__file__).resolve().parent.parent.parent
PORT_DIR = REPO / "firmware" / "runtime" / "ports" / "cortex_m4"
MACHINE = "mps2-an386"
READY_TIMEOUT_S = 20.0


@dataclass(frozen=True)
class M4Build:
    """One firmware build for the Cortex-M4 port: `make -C firmware/runtime/ports/cortex_m4 GOAL VARS...`
    writes `elf_name` into OUT; `sources` (files or folders) key the cache."""

    goal: str
    elf_name: str
    variables: tuple[str, ...] = ()
    sources: tuple[Path, ...] = ()


def cache_dir() -> Path:
    """Where Cortex-M4 builds are kept: the starters' cache root, folder qemu."""
    return cache_root() / "qemu"


def _files(paths: tuple[Path, ...]) -> list[Path]:
    found: list[Path] = []
    for path in (PORT_DIR, *paths):
        if path.is_dir():
            found += sorted(p for p in path.rglob("*") if p.is_file() and p.suffix in (".c", ".h", ".ld", "")
                            and "__pycache__" not in p.parts)
        elif path.is_file():
            found.append(path)
    return found


def _compiler_id() -> str:
    gcc = shutil.which("arm-none-eabi-gcc")
    if gcc is None or shutil.which("make") is None:
        raise ConfigError("qemu: building the firmware needs arm-none-eabi-gcc and make "
                          "(apt-get install gcc-arm-none-eabi libnewlib-arm-none-eabi make)")
    out = subprocess.run([gcc, "--version"], capture_output=True, text=True, timeout=30)
    return out.stdout.splitlines()[0] if out.stdout else gcc


def build_m4(build: M4Build, out_dir: Path | None = None) -> Path:
    """The ELF of `build`, made now unless an identical build (same sources, variables, compiler) exists."""
    digest = hashlib.sha256(_compiler_id().encode() + b"\0" + "\0".join((build.goal, *build.variables)).encode())
    for path in _files(build.sources):
        digest.update(str(path.relative_to(REPO)).encode() + b"\0" + path.read_bytes())
    directory = (out_dir or cache_dir()) / f"{build.goal}-{digest.hexdigest()[:16]}"
    elf = directory / build.elf_name
    if elf.is_file():
        return elf
    directory.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=directory.name + ".", dir=directory.parent))
    try:
        done = subprocess.run(["make", "-s", "-C", str(PORT_DIR), build.goal, f"OUT={tmp}", *build.variables],
                              capture_output=True, text=True, timeout=300)
        if done.returncode != 0 or not (tmp / build.elf_name).is_file():
            lines = (done.stderr or done.stdout).strip().splitlines() or ["no output"]
            first = next((ln for ln in lines if "error" in ln), lines[0])
            raise ConfigError(f"qemu: building {build.goal} for the Cortex-M4 failed: {first.strip()}")
        try:
            os.replace(tmp, directory)  # atomic: a concurrent build never sees a half-written folder
        except OSError:
            if not elf.is_file():  # another process made it first: theirs is the same build
                raise
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return elf


def qemu_command(elf: Path, serial: str, extra: tuple[str, ...] = ()) -> list[str]:
    """The QEMU command line of a firmware ELF, its UART0 on `serial` (a tty path, or "pty")."""
    qemu = shutil.which("qemu-system-arm")
    if qemu is None:
        raise ConfigError("qemu: qemu-system-arm is not installed (apt-get install qemu-system-arm)")
    return [qemu, "-M", MACHINE, "-nographic", "-kernel", str(elf), "-serial", serial, "-monitor", "none", *extra]


def start_qemu(elf: Path, tty_path: str, extra: tuple[str, ...] = (), label: str = "qemu") -> Started:
    """Start QEMU on `elf` with the board's UART0 on `tty_path`; returns once QEMU has opened it
    (or fails with its one-line complaint). QEMU's messages go to a temporary file (a pipe nobody
    reads could block it), which the Started keeps for its exit note. Bytes sent before the
    firmware enables its UART wait in the tty."""
    log = tempfile.TemporaryFile()
    try:
        process = spawn(qemu_command(elf, tty_path, extra), stdin=subprocess.DEVNULL, stdout=log,  # dies with us
                        stderr=subprocess.STDOUT, start_new_session=True)
    except OSError as exc:
        log.close()
        raise LinkError(f"qemu: cannot start qemu-system-arm ({exc.strerror})") from None
    try:
        _wait_open(process, tty_path, log)
    except BaseException:
        reap(process)
        log.close()
        raise
    return Started(process, tty_path, f"{label} (pid {process.pid})", log)


@dataclass(frozen=True)
class QemuStarter:
    """`qemu:NAME`: the target's firmware built for the Cortex-M4 (`build`: options -> what to make),
    run in QEMU with its UART0 on the slave of the host's pty pair (hilbench.targets.starters)."""

    build: Callable[[object], M4Build]
    name: str = "firmware"
    kind: str = "qemu"
    serves_host_pty: bool = True

    def start(self, options: object, host_tty: str | None) -> Started:
        assert host_tty is not None
        return start_qemu(build_m4(self.build(options)), host_tty, label=f"qemu:{self.name}")


@dataclass(frozen=True)
class _ElfStarter:
    """`qemu:PATH`: an ELF built for the MPS2 AN386 with a hilbench Cortex-M4 port."""

    elf: Path
    name: str
    kind: str = "qemu"
    serves_host_pty: bool = True

    def start(self, options: object, host_tty: str | None) -> Started:
        assert host_tty is not None
        if not self.elf.is_file():
            raise ConfigError(f"qemu:{self.name}: no ELF there (build the firmware's Cortex-M4 port first, "
                              "e.g. make -C firmware/runtime/ports/cortex_m4 foc)")
        return start_qemu(self.elf, host_tty, label=f"qemu:{self.name}")


def qemu_path_starter(path: str) -> _ElfStarter:
    """`qemu:PATH`: a firmware ELF for the MPS2 AN386 (firmware/runtime/ports/cortex_m4), run as it is."""
    return _ElfStarter(Path(path).expanduser(), str(path))


def _wait_open(process: subprocess.Popen[bytes], tty_path: str, log: IO[bytes]) -> None:
    """Until QEMU holds tty_path open (its /proc fd table names it), or it exits."""
    deadline = time.monotonic() + READY_TIMEOUT_S
    fd_dir = Path(f"/proc/{process.pid}/fd")
    while True:
        if process.poll() is not None:
            log.seek(0)
            tail = log.read().decode(errors="replace").strip().splitlines()[-1:] or ["no output"]
            raise LinkError(f"qemu {MACHINE}: exited with code {process.returncode}: {tail[0]}")
        try:
            if any(os.readlink(fd) == tty_path for fd in fd_dir.iterdir()):
                return
        except OSError:
            if not fd_dir.parent.exists():  # no /proc (not Linux): the handshake's retries cover it
                return
        if time.monotonic() > deadline:
            raise LinkError(f"qemu {MACHINE}: did not open {tty_path} within {READY_TIMEOUT_S:.0f} s")
        time.sleep(0.01)


def main(argv: list[str] | None = None) -> None:
    """Build a target's Cortex-M4 firmware and run it in QEMU with its UART on a pty QEMU makes
    (QEMU prints the path; connect to it like a board: hilbench run --target /dev/pts/N)."""
    import argparse

    from hilbench.targets.registry import get_profile

    parser = argparse.ArgumentParser(prog="python -m hilbench.targets.qemu", description=main.__doc__)
    parser.add_argument("name", help="a target with a Cortex-M4 build (an1017, foc)")
    parser.add_argument("--build-only", action="store_true", help="print the ELF's path and exit")
    args = parser.parse_args(argv)
    profile = get_profile(args.name)
    starter = profile.starters.get("qemu")
    if not isinstance(starter, QemuStarter):
        raise SystemExit(f"qemu: target {args.name!r} has no Cortex-M4 build")
    elf = build_m4(starter.build(profile.default_options()))
    if args.build_only:
        print(elf)
        return
    os.execv(qemu_command(elf, "pty")[0], qemu_command(elf, "pty"))


__all__ = ["M4Build", "MACHINE", "PORT_DIR", "QemuStarter", "build_m4", "cache_dir", "main", "qemu_command",
           "qemu_path_starter", "start_qemu"]


if __name__ == "__main__":
    main()
