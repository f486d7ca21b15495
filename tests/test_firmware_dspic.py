"""Issue 12, the dsPIC30F2010 port: compiles warning-free, and its RAM fits the chip's 512 bytes.

XC16 cannot be installed here, so the port (ports/dspic30f2010/main.c with the firmware, the
runtime and the C library) is compiled with host gcc, strict flags, against hostcheck/xc.h, a
register header written for this test.

RAM figure = static + a computed stack bound:
- static: the RAM objects (.bss/.data, not const: XC16 keeps const data in program memory) of the
  host build. No RAM object holds a pointer and x86-64 aligns uint32_t to 4 bytes where the dsPIC
  aligns to 2, so this is an upper bound of the dsPIC's figure.
- stack: the deepest call path of the same sources built for a 16-bit-int, 16-bit-pointer target
  (avr-gcc: -fstack-usage frame sizes, call edges from the disassembly; every indirect call — the
  runtime calling the firmware's declared bodies and callbacks — counted as a call of any of them,
  an upper bound), with the dsPIC's larger costs added: +2 bytes per
  call (its return address is 4 bytes, the AVR's 2) and +24 bytes per interrupt level (PC, SR and
  IPL pushed by the hardware: 4; W0-W7 saved by the compiler for an ISR that calls functions: 16;
  RCOUNT and one spare word: 4). Every interrupt of the port has priority 4, so they never nest:
  on main's stack sits one ISR frame, the deepest. Two builds: the 30F2010's default, the lockstep
  profile (docs/board.md "Does it fit": no real time, so only the UART1 RX and FLTA interrupts), and
  the real-motor build (`make MODE=motor`: real time on the chip's timers, the PWM, Timer1, Timer2,
  FLTA, UART1 RX interrupts and the halls' CN, IC7 and IC8).
"""

from __future__ import annotations

import re
import subprocess
from pathlib import Path

import pytest

from _firmware import require_tool
from c_build import STRICT_FLAGS
from hilbench.targets.sil import FIRMWARE_DIR, PROTOCOL_DIR, RUNTIME_DIR, RUNTIME_SOURCES

PORT = FIRMWARE_DIR / "ports" / "dspic30f2010"
SOURCES = (PORT / "main.c", FIRMWARE_DIR / "an1017.c", *RUNTIME_SOURCES)
#: the Makefile's defines of every build of the port, and its include folders
BASE_DEFS = ("-DHBP_MAX_ADC=3u", "-DHBP_MAX_TELEMETRY=3u", "-DHBP_MAX_EDGES=3u", "-DHBP_MAX_BATCH=17u", "-DHRT_PORT_HW=1",
             "-DHRT_DESCRIBE=0", "-DHRT_PREDICT_BYTES=0u", "-DHRT_SPECULATE=0")
INCLUDES = (f"-I{PORT / 'hostcheck'}", f"-I{FIRMWARE_DIR}", f"-I{RUNTIME_DIR}", f"-I{PROTOCOL_DIR}")
#: the 30F2010's build: its board profile (PROFILE=lockstep, the Makefile's default for the chip;
#: docs/board.md "Does it fit"), lockstep sessions only
LOCKSTEP_PROFILE = ("-DHRT_REALTIME=0",)
DEFS = (*BASE_DEFS, *LOCKSTEP_PROFILE, *INCLUDES)
#: PROFILE=full (the 30F4012's default): real time too
FULL_DEFS = (*BASE_DEFS, *INCLUDES)
MOTOR = ("-DHIL_LOCAL_HALLS", "-DHIL_DRIVE_BRIDGE", "-DHRT_MONITOR=1")
#: the firmware's functions the runtime calls through its declaration (an1017_firmware), by the
#: function that holds the indirect call; any other holder is the scheduler, which calls the bodies
CALLBACKS = {
    "pwm_boundary": {"body_pwm"},
    "expire": {"body_timer1", "body_boot"},
    "apply_edge": {"body_hall_a", "body_hall_b", "body_hall_c"},
    "hrt_span_begin": {"body_main"},
    "hrt_rt_main": {"body_main"},
    "hrt_param_candidate": {"decl_param_get"},
    "hrt_param_write": {"decl_param_set", "decl_param_check"},
    "hrt_report": {"decl_report"},
    "on_describe": {"decl_param_get"},
    "on_get": {"decl_param_get"},
    "hrt_link_handle": {"decl_start", "decl_stop"},
    "hrt_link_watchdog": {"decl_stop"},
    "hbp_send_frame": {"hrt_port_send"},
    "put_crc": {"hrt_port_send"},
}
DSPIC30F2010_RAM_BYTES = 512
#: the 30F2010's (lockstep profile) interrupt handlers; PROFILE=full adds PWM, Timer1 and Timer2
ISRS = ("_FLTAInterrupt", "_U1RXInterrupt")
#: the real-motor build's: real time and the motor's halls
MOTOR_ISRS = ("_PWMInterrupt", "_T1Interrupt", "_T2Interrupt", "_FLTAInterrupt", "_U1RXInterrupt", "_CNInterrupt",
              "_IC7Interrupt", "_IC8Interrupt")
#: the builds whose RAM is bounded: defines, interrupt handlers, the static RAM objects
RAM_BUILDS = {
    "lockstep": (DEFS, ISRS, {"fw", "host_link"}),  # no clock overflows, no board S2
    "motor": ((*BASE_DEFS, *INCLUDES, *MOTOR), MOTOR_ISRS, None),
}
DSPIC_EXTRA_PER_CALL = 2
DSPIC_ISR_CONTEXT = 24
MARGIN_BYTES = 32


@pytest.mark.parametrize("options", [DEFS, (*FULL_DEFS, "-DHIL_LOCAL_POT"),
                                     (*DEFS, "-DAN1017_VARIANT=AN1017_VARIANT_V11"), FULL_DEFS,
                                     (*BASE_DEFS, *INCLUDES, *MOTOR)],
                         ids=["default", "options", "v11", "full", "motor"])
def test_dspic_port_compiles_warning_free(gcc: str, tmp_path: Path, options: tuple[str, ...]) -> None:
    for source in (*SOURCES, PORT / "an1017_dspic30f2010.c"):  # each source, and the Makefile's one unit of them
        result = subprocess.run([gcc, *STRICT_FLAGS, "-Os", *options, "-c", str(source), "-o",
                                 str(tmp_path / (source.stem + ".o"))], capture_output=True, text=True, timeout=120)
        assert result.returncode == 0, result.stderr


@pytest.mark.parametrize("options", [("-DHIL_DRIVE_BRIDGE",), ("-DHIL_DRIVE_BRIDGE", "-DHIL_LOCAL_POT")],
                         ids=["bridge", "bridge+pot"])
def test_dspic_port_refuses_to_drive_the_bridge_from_simulated_halls(gcc: str, tmp_path: Path,
                                                                     options: tuple[str, ...]) -> None:
    """Issue 24: HIL_DRIVE_BRIDGE without the motor's own halls would commutate a real motor from the
    plant's simulated rotor; the port stops the compiler with #error."""
    done = subprocess.run([gcc, *STRICT_FLAGS, "-Os", *DEFS, *options, "-c", str(PORT / "main.c"), "-o",
                           str(tmp_path / "main.o")], capture_output=True, text=True, timeout=120)
    assert done.returncode != 0 and "HIL_DRIVE_BRIDGE needs HIL_LOCAL_HALLS" in done.stderr, done.stderr


def test_dspic_defines_are_the_makefiles() -> None:
    """DEFS and FULL_DEFS are what `make size` compiles with (PROFILE=lockstep and PROFILE=full)."""
    require_tool("make", "the dsPIC Makefile (apt: make)")
    for make_args, defs in (((), DEFS), (("PROFILE=full",), FULL_DEFS)):
        done = subprocess.run(["make", "-s", "-n", "--no-print-directory", "-C", str(PORT), "size", *make_args],
                              capture_output=True, text=True, timeout=60, check=True)
        makefile = [f for f in done.stdout.split() if f.startswith("-D") and not f.startswith("-DAN1017_VARIANT")]
        assert makefile == [f for f in defs if f.startswith("-D")], (make_args, makefile)


@pytest.mark.parametrize("options", [(), ("-DHIL_DRIVE_BRIDGE",)], ids=["pot", "pot+bridge"])
def test_dspic_lockstep_profile_refuses_the_local_pot(gcc: str, tmp_path: Path, options: tuple[str, ...]) -> None:
    """HIL_LOCAL_POT reads the pot in the real-time PWM interrupt, which the lockstep profile has not."""
    done = subprocess.run([gcc, *STRICT_FLAGS, "-Os", *DEFS, "-DHIL_LOCAL_POT", *options, "-c", str(PORT / "main.c"),
                           "-o", str(tmp_path / "main.o")], capture_output=True, text=True, timeout=120)
    assert done.returncode != 0 and "HIL_LOCAL_POT reads the pot" in done.stderr, done.stderr


def static_ram_bytes(gcc: str, tmp_path: Path, defs: tuple[str, ...] = DEFS) -> dict[str, int]:
    """RAM objects (.bss/.data) of the host build and their sizes."""
    objects = []
    for source in SOURCES:
        obj = tmp_path / (source.stem + ".o")
        subprocess.run([gcc, *STRICT_FLAGS, "-Os", "-fno-pic", "-fno-pie", *defs, "-c", str(source), "-o", str(obj)],
                       check=True, capture_output=True, timeout=120)
        objects.append(str(obj))
    out = subprocess.run(["nm", "-S", *objects], capture_output=True, text=True, check=True, timeout=30).stdout
    sizes = {}
    for line in out.splitlines():
        parts = line.split()
        if len(parts) == 4 and parts[2] in "bBdD":
            sizes[parts[3]] = int(parts[1], 16)
    return sizes


def stack_bound_bytes(tmp_path: Path, defs: tuple[str, ...] = DEFS,
                      isrs: tuple[str, ...] = ISRS) -> tuple[int, dict[str, tuple[int, list[str]]]]:
    avr_gcc = require_tool("avr-gcc", "the computed stack bound of the dsPIC port (apt: gcc-avr avr-libc)")
    elf = tmp_path / "dspic_port_16bit.elf"
    build = tmp_path / "su"
    build.mkdir()
    cmd = [avr_gcc, "-mmcu=atmega328p", "-std=c99", "-Os", "-fstack-usage", *defs, *(str(s) for s in SOURCES),
           str(PORT / "hostcheck" / "sfr.c"), "-o", str(elf)]
    result = subprocess.run(cmd, capture_output=True, text=True, timeout=180, cwd=build)
    assert result.returncode == 0, result.stderr
    frames: dict[str, int] = {}
    for su in build.glob("*.su"):
        for line in su.read_text().splitlines():
            where, size, _kind = line.split("\t")
            frames[where.rsplit(":", 1)[1]] = max(frames.get(where.rsplit(":", 1)[1], 0), int(size))
    disasm = subprocess.run(["avr-objdump", "-d", str(elf)], capture_output=True, text=True, check=True,
                            timeout=60).stdout
    calls: dict[str, set[str]] = {}
    indirect: set[str] = set()  # functions with an icall: the runtime calling the declaration
    current = None
    for line in disasm.splitlines():
        head = re.match(r"^[0-9a-f]+ <([^>]+)>:$", line)
        if head:
            current = head.group(1)
            continue
        if current and re.search(r"\ti(call|jmp)\b", line):
            indirect.add(current)
        call = re.search(r"\t(r?call|jmp|rjmp)\t.*<([^>+]+)>$", line)
        if current and call and call.group(2) != current and call.group(2) in frames:
            calls.setdefault(current, set()).add(call.group(2))
    bodies = {fn for fn in frames if fn.startswith("body_")}
    assert bodies and indirect, (bodies, indirect)
    for fn in indirect:
        calls.setdefault(fn, set()).update(CALLBACKS.get(fn, bodies))

    def deepest(fn: str, seen: tuple[str, ...] = (), skip: tuple[str, ...] = ()) -> tuple[int, list[str]]:
        assert fn not in seen, f"recursion through {fn}"
        best, path = 0, []
        for callee in calls.get(fn, ()):
            if callee in skip:
                continue
            depth, sub = deepest(callee, seen + (fn,), skip)
            depth += 2 + DSPIC_EXTRA_PER_CALL  # the return address, dsPIC-sized
            if depth > best:
                best, path = depth, sub
        return frames.get(fn, 0) + best, [fn, *path]

    paths = {fn: deepest(fn) for fn in ("main", *isrs)}
    if "_PWMInterrupt" in paths:  # Timer1 runs in hardware (hrt_port_timer): its body runs from _T1Interrupt
        paths["_PWMInterrupt"] = deepest("_PWMInterrupt", skip=("body_timer1",))
    # main's deepest path and one ISR's on top (all at priority 4: they never nest)
    return paths["main"][0] + max(paths[f][0] for f in isrs) + DSPIC_ISR_CONTEXT, paths


@pytest.mark.parametrize("build", sorted(RAM_BUILDS))
def test_dspic_port_ram_fits_512_bytes(gcc: str, tmp_path: Path, capsys, build: str) -> None:
    defs, isrs, statics = RAM_BUILDS[build]
    sizes = static_ram_bytes(gcc, tmp_path, defs)
    assert statics is None or set(sizes) == statics, sizes
    static = sum(sizes.values())
    stack, paths = stack_bound_bytes(tmp_path, defs, isrs)
    assert "hrt_link_handle" in paths["main"][1], paths["main"]  # the analysis found the frame path
    assert all(paths[f][0] > 0 for f in isrs), {f: paths[f] for f in isrs}  # every handler is in the build
    with capsys.disabled():
        print(f"\ndsPIC30F2010 RAM ({build}): static {static} B ({', '.join(f'{k} {v}' for k, v in sorted(sizes.items()))}) "
              f"+ stack bound {stack} B = {static + stack} of {DSPIC30F2010_RAM_BYTES} B (margin {MARGIN_BYTES} B "
              f"required); deepest main path {' > '.join(paths['main'][1])}")
    assert static + stack <= DSPIC30F2010_RAM_BYTES - MARGIN_BYTES


def run_port_harness(gcc: str, tmp_path: Path, name: str, c_main: str, defs: tuple[str, ...]) -> list[str]:
    """main.c's statics and functions driven by a test's own C ``main`` (the port's renamed port_main),
    built with host gcc against hostcheck's SFRs; what it prints, split into words."""
    harness = tmp_path / f"{name}.c"
    harness.write_text(f'#define main port_main\n#include "{PORT / "main.c"}"\n#undef main\n#include <stdio.h>\n'
                       + c_main)
    exe = tmp_path / name
    done = subprocess.run([gcc, "-std=c99", *defs, str(harness), *(str(s) for s in SOURCES[1:]),
                           str(PORT / "hostcheck" / "sfr.c"), "-o", str(exe)], capture_output=True, text=True,
                          timeout=120)
    assert done.returncode == 0, done.stderr
    return subprocess.run([str(exe)], capture_output=True, text=True, timeout=10, check=True).stdout.split()


def test_dspic_clock_counts_a_pending_timer2_overflow(gcc: str, tmp_path: Path) -> None:
    """Issue 24 (PROFILE=full, where Timer2 also times the motor build's hall captures): hrt_port_now() inside a priority-4 ISR, where the Timer2 overflow interrupt cannot
    run yet: TMR2 has wrapped to a low value and T2IF is set, so the clock is one overflow later,
    not 65 536 Tcy earlier (which could trip the watchdog). A high TMR2 read with T2IF set was read
    before the overflow and stays as it is."""
    lines = run_port_harness(gcc, tmp_path, "clock", r'''
int main(void) {
    tcy_high = 7u;
    TMR2 = 0xFFF0u; IFS0bits.T2IF = 0;
    printf("%lu\n", (unsigned long)hrt_port_now());
    TMR2 = 0x0005u; IFS0bits.T2IF = 1;   /* wrapped, interrupt pending */
    printf("%lu\n", (unsigned long)hrt_port_now());
    TMR2 = 0xFFFEu; IFS0bits.T2IF = 1;   /* read before the wrap that set the flag */
    printf("%lu\n", (unsigned long)hrt_port_now());
    return 0;
}
''', FULL_DEFS)
    assert [int(v) for v in lines] == [7 * 65536 + 0xFFF0, 8 * 65536 + 5, 7 * 65536 + 0xFFFE]


def test_dspic_lockstep_profile_clock_is_timer3_timer2(gcc: str, tmp_path: Path) -> None:
    """The lockstep profile's clock: Timer3:Timer2 as one 32-bit timer, TMR2 read first (it latches TMR3
    into TMR3HLD: hostcheck's TMR2 does too), no overflow interrupt. TMR3HLD starts stale, so a clock
    that read it before TMR2 would return its stale high word."""
    out = run_port_harness(gcc, tmp_path, "clock32", r'''
int main(void) {
    init_timers();
    TMR2 = 0xFFF0u; TMR3 = 0x0007u; TMR3HLD = 0x1234u;   /* the holding register still holds an old high word */
    printf("%lu %u %u %u\n", (unsigned long)hrt_port_now(), (unsigned)T2CON, (unsigned)PR2, (unsigned)PR3);
    return 0;
}
''', DEFS)
    assert [int(v) for v in out] == [7 * 65536 + 0xFFF0, 0x8008, 0xFFFF, 0xFFFF]


def test_dspic_board_s2_is_debounced(gcc: str, tmp_path: Path) -> None:
    """Issue 24 (PROFILE=full; the lockstep profile's S2 is the bench's, the Sensors bit): the board's S2 contact bounces; a level counts once it held 20 ms (400 000 Tcy), so a
    press with bounces on both edges toggles start/stop once for the press and once for the release."""
    out = run_port_harness(gcc, tmp_path, "s2", r'''
int main(void) {
    /* (time in us, raw pressed level): bounces at 0-3 ms, pressed until 100 ms, bounces at release */
    static const unsigned long t_us[] = {0, 500, 900, 1500, 3000, 10000, 22000, 23100, 50000,
                                         100000, 100400, 101000, 101300, 110000, 121400, 129900, 130500};
    static const unsigned char raw[] = {1, 0, 1, 0, 1, 1, 1, 1, 1, 0, 1, 0, 1, 0, 0, 0, 0};
    uint8_t level = 0u;
    unsigned i;
    for (i = 0u; i < sizeof raw; i++) {
        if (s2_debounced(raw[i], (uint32_t)(t_us[i] * 20ul), &level)) {
            printf("%lu:%u ", t_us[i], (unsigned)level);
        }
    }
    printf("\n");
    return 0;
}
''', FULL_DEFS)
    # pressed for good at 3 ms (the last bounce) -> counts at 23.1 ms, the first sample 20 ms later;
    # released for good at 110 ms -> not at 129.9 ms (19.9 ms), at 130.5 ms
    assert out == ["23100:1", "130500:0"]
