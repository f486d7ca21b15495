"""The builds of the one FOC source (firmware/foc) on the runtime: each records what the in-process
core records, column for column, and each compiles warning-free with its compiler's strict flags.

- `sil:foc` (this host, a process on a pty): the whole servo scenario is a case of
  tests/test_golden_recordings.py (held to the in-process servo's golden digests); here at 100 us;
- `qemu:foc` (a Cortex-M4 in QEMU's mps2-an386) and the ATmega1284P in simavr: a shorter run,
  against inprocess:foc's recording of the same run;
- the TMS320F2812 port: compiled and linked with gcc and clang against the register header written
  for the test (TI's compiler is not available), and the firmware's sources free of 8-bit types.
"""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from _firmware import require_tool
from c_build import STRICT_FLAGS
from hilbench import read_recording
from hilbench.targets.foc import build

pytestmark = pytest.mark.slow

REPO = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(REPO / "tests" / "golden"))
from golden import SERVO  # noqa: E402

F2812 = build.FIRMWARE_DIR / "ports" / "f2812"


def _record(spec: str, out: Path, seconds: float, *sets: str) -> dict:
    argv = [sys.executable, "-m", "hilbench", "run", str(REPO / SERVO), "--target", spec, "--duration", str(seconds),
            "--no-ui", "--no-control", "--record", str(out),
            "--set", "link.timeout_ms=10000"]  # a simulator starved by a loaded machine is slow, not lost
    for item in sets:
        argv += ["--set", item]
    done = subprocess.run(argv, capture_output=True, text=True, timeout=900, cwd=REPO)
    assert out.exists(), f"{spec}: no recording (exit {done.returncode}): {done.stderr.strip()[-600:]}"
    return read_recording(out).columns


def _assert_same(got: dict, want: dict, label: str) -> None:
    assert sorted(got) == sorted(want), label
    assert len(next(iter(want.values()))) >= 1000, label
    changed = [name for name in want if not np.array_equal(np.asarray(got[name]), np.asarray(want[name]))]
    assert not changed, f"{label}: columns differ from inprocess:foc: {changed}"


def test_sil_foc_at_two_halves_per_exchange_equals_inprocess(gcc, tmp_path: Path) -> None:
    """100 us exchanges: two halves each, the Drive the mean of their duties on both sides."""
    _assert_same(_record("sil:foc", tmp_path / "sil.npz", 0.5, "link.period_us=100"),
                 _record("inprocess:foc", tmp_path / "inprocess.npz", 0.5, "link.period_us=100"), "sil:foc at 100 us")


def test_qemu_foc_equals_inprocess(tmp_path: Path) -> None:
    require_tool("qemu-system-arm", "the Cortex-M4 target (apt: qemu-system-arm)")
    require_tool("arm-none-eabi-gcc", "the Cortex-M4 build (apt: gcc-arm-none-eabi libnewlib-arm-none-eabi)")
    _assert_same(_record("qemu:foc", tmp_path / "qemu.npz", 0.5),
                 _record("inprocess:foc", tmp_path / "inprocess.npz", 0.5), "qemu:foc")


def test_qemu_foc_builds_with_negative_settings(tmp_path: Path) -> None:
    """A [target] table with a negative setting (a calibrated angle below zero) reaches make's shell
    as -DFOC_CFG_CALIBRATED_ANGLE=(-1250L): quoted, it builds."""
    require_tool("arm-none-eabi-gcc", "the Cortex-M4 build (apt: gcc-arm-none-eabi libnewlib-arm-none-eabi)")
    require_tool("make", "the Cortex-M4 Makefile (apt: make)")
    from hilbench.targets.foc.firmware import FocOptions
    from hilbench.targets.qemu import build_m4

    options = FocOptions(calibrated_angle=-1250, learn_index=False)
    assert "-DFOC_CFG_CALIBRATED_ANGLE=(-1250L)" in build.config_defines(options)
    assert build_m4(build.qemu_build(options), tmp_path).is_file()


def test_simavr_foc_equals_inprocess(tmp_path: Path) -> None:
    """The ATmega1284P (8-bit core, 16-bit int, the 16-bit-limb IQ24 product) in simavr."""
    require_tool("avr-gcc", "the AVR build (apt: gcc-avr avr-libc)")
    require_tool("simavr", "running the AVR build (apt: simavr libsimavr-dev)")
    _assert_same(_record("simavr:foc", tmp_path / "avr.npz", 0.2),
                 _record("inprocess:foc", tmp_path / "inprocess.npz", 0.2), "simavr:foc")


@pytest.mark.parametrize("cc", ["gcc", "clang"])
@pytest.mark.parametrize("defines", [(), ("-DHIL_DRIVE_BRIDGE", "-DHIL_LOCAL_SENSORS")], ids=["bench", "board"])
def test_f2812_port_compiles_and_links_warning_free(cc: str, defines: tuple[str, ...], tmp_path: Path) -> None:
    compiler = require_tool(cc, "the F2812 port's compile check")
    sources = [F2812 / "main.c", F2812 / "hostcheck" / "regs.c", *build.SOURCES, build.FIRMWARE_DIR / "foc_hrt.c",
               build.RUNTIME_DIR / "hrt.c", build.RUNTIME_DIR / "hrt_link.c", build.PROTOCOL_DIR / "hbp.c",
               build.PROTOCOL_DIR / "hbp_messages.c"]
    includes = [f"-I{d}" for d in (F2812 / "hostcheck", build.FIRMWARE_DIR, build.RUNTIME_DIR, build.PROTOCOL_DIR)]
    done = subprocess.run([compiler, *STRICT_FLAGS, "-O2", "-DHRT_PORT_HW=1", *defines, *includes,
                           *(str(s) for s in sources), "-o", str(tmp_path / "f2812")],
                          capture_output=True, text=True, timeout=180)
    assert done.returncode == 0, done.stderr


def test_the_whole_f2812_program_has_no_8_bit_types(gcc: str, tmp_path: Path) -> None:
    """What the C28x (no int8_t/uint8_t: CHAR_BIT = 16) asks of the runtime, the protocol library and
    the port too (docs/foc.md): every source of the F2812 program compiles with them poisoned (octets
    are hbp_u8, uint_least8_t: 16 bits there)."""
    sources = [F2812 / "main.c", F2812 / "hostcheck" / "regs.c", *build.SOURCES, build.FIRMWARE_DIR / "foc_hrt.c",
               build.RUNTIME_DIR / "hrt.c", build.RUNTIME_DIR / "hrt_link.c", build.PROTOCOL_DIR / "hbp.c",
               build.PROTOCOL_DIR / "hbp_messages.c"]
    includes = [f"-I{d}" for d in (F2812 / "hostcheck", build.FIRMWARE_DIR, build.RUNTIME_DIR, build.PROTOCOL_DIR)]
    for source in sources:
        done = subprocess.run([gcc, *STRICT_FLAGS, "-DHRT_PORT_HW=1", "-DC28X_POISON_UINT8", "-include",
                               str(F2812 / "hostcheck" / "c28x_types.h"), *includes, "-c", str(source),
                               "-o", str(tmp_path / "x.o")], capture_output=True, text=True, timeout=120)
        assert done.returncode == 0, f"{source.name}: {done.stderr}"


def test_f2812_port_refuses_to_drive_the_bridge_from_simulated_sensors(gcc, tmp_path: Path) -> None:
    """HIL_DRIVE_BRIDGE without HIL_LOCAL_SENSORS would switch a real bridge from the plant's
    currents and encoder: the build stops with one line that says so."""
    includes = [f"-I{d}" for d in (F2812 / "hostcheck", build.FIRMWARE_DIR, build.RUNTIME_DIR, build.PROTOCOL_DIR)]
    done = subprocess.run([gcc, *STRICT_FLAGS, "-DHRT_PORT_HW=1", "-DHIL_DRIVE_BRIDGE", *includes, "-c",
                           str(F2812 / "main.c"), "-o", str(tmp_path / "main.o")], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode != 0 and "HIL_DRIVE_BRIDGE needs HIL_LOCAL_SENSORS" in done.stderr, done.stderr


@pytest.mark.parametrize("source", build.SOURCES, ids=lambda p: p.name)
def test_firmware_sources_have_no_8_bit_types(gcc, source: Path, tmp_path: Path) -> None:
    """What the C28x (no int8_t/uint8_t: CHAR_BIT = 16) asks of the firmware, checked with them poisoned."""
    done = subprocess.run([gcc, *STRICT_FLAGS, "-DC28X_POISON_UINT8", "-include",
                           str(F2812 / "hostcheck" / "c28x_types.h"), f"-I{build.FIRMWARE_DIR}", "-c", str(source),
                           "-o", str(tmp_path / "x.o")], capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr


@pytest.mark.parametrize("goal,tool,why", [
    ("avr", "avr-gcc", "the AVR build (apt: gcc-avr avr-libc)"),
    ("cortex_m4", "arm-none-eabi-gcc", "the Cortex-M4 build (apt: gcc-arm-none-eabi libnewlib-arm-none-eabi)"),
])
def test_mcu_builds_are_warning_free(goal: str, tool: str, why: str, tmp_path: Path) -> None:
    """The Makefiles build with -Werror and the strict flags: a warning fails the build."""
    require_tool(tool, why)
    require_tool("make", "the firmware Makefiles (apt: make)")
    folder = build.FIRMWARE_DIR / "ports" / "avr" if goal == "avr" else REPO / "firmware" / "runtime" / "ports" / "cortex_m4"
    done = subprocess.run(["make", "-s", "-C", str(folder), *([] if goal == "avr" else ["foc"]), f"OUT={tmp_path}"],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0 and not done.stderr.strip(), done.stdout + done.stderr


def test_sil_foc_start_while_running_keeps_the_duties(gcc) -> None:
    """A Start (`hilbench ctl start`) while the firmware runs changes nothing in the model
    (foc_start only acts when stopped or faulted): the SIL build must not drop its duties to zero
    for the span either, exchange for exchange against inprocess:foc."""
    import random

    from hilbench.bench.launcher import open_target
    from hilbench.protocol import MODE_LOCKSTEP, PROTOCOL_VERSION, HostHello, Sensors

    hello = HostHello(0, PROTOCOL_VERSION, 50, MODE_LOCKSTEP, 0)
    with open_target("sil:foc", timeout_s=2.0) as sil, open_target("inprocess:foc") as inproc:
        targets = (inproc.target, sil.target)
        assert targets[0].hello(hello) == targets[1].hello(hello)
        rng = random.Random(5)
        encoder = 0
        states = set()
        for t in targets:
            t.start()
        for k in range(5000):
            if k in (1000, 4500):  # aligning (4000 halves), then in the closed loop
                for t in targets:
                    t.start()
            encoder = (encoder + rng.randint(0, 3)) & 0xFFFF
            adc = (rng.randint(1900, 2200), rng.randint(1900, 2200), 3000)
            sensors = Sensors((k + 1) & 0xFF, 0, (), encoder, adc)
            drives = [tuple(t.step(sensors)) for t in targets]
            assert drives[0] == drives[1], (k, drives)
            states.add(drives[0][5])
        assert {1, 2} <= states  # the Starts fell in the alignment and in the closed loop
