"""The C firmware core in this process, without the protocol and without hilbench's glue (issue 12:
one C source for the board, the host build and the in-process core; the extension
hilbench.targets.an1017._core is that source behind a CPython glue, tests/test_an1017_core.py).

The firmware and the runtime are compiled here as a plain shared library with gcc and called through
ctypes: one runtime span per period (hrt_span_begin / hrt_span_edge / hrt_span_end with the
Sensors' inputs, edges and pot), hrt_report for the Drive, the firmware's command and parameter
entry points for Start/Stop and writes the Python model accepts. Every Drive must equal the Python
model's (hilbench/targets/an1017/firmware.py through An1017Target) on the seeded random streams.
"""

from __future__ import annotations

import ctypes
from pathlib import Path

import pytest

from _firmware import Command, random_stream
from c_build import build_c
from hilbench.protocol import HostHello, MODE_LOCKSTEP, PROTOCOL_VERSION, Sensors
from hilbench.targets.an1017.firmware import An1017Options
from hilbench.targets.an1017.target import An1017Target
from hilbench.targets.sil import FIRMWARE_DIR, RUNTIME_DIR

STATE_BYTES = 512  # more than sizeof(an1017_t) on any host (124 on x86-64)
OK = 0
N_TELEMETRY = 3  # the library's -DHBP_MAX_TELEMETRY


class Drive(ctypes.Structure):
    """hbp_drive_t (= hrt_report_t): seq, the duties, the flags' fields one byte each, the telemetry."""

    _fields_ = [("seq", ctypes.c_uint8), ("duty", ctypes.c_uint16 * 3), ("output_mode", ctypes.c_uint8),
                ("state", ctypes.c_uint8), ("sector", ctypes.c_uint8), ("ccw", ctypes.c_uint8),
                ("req_ccw", ctypes.c_uint8), ("fault", ctypes.c_uint8), ("n_telemetry", ctypes.c_uint8),
                ("telemetry", ctypes.c_int16 * N_TELEMETRY)]


def load_core_library(out: Path, defines: tuple[str, ...] = ()) -> ctypes.CDLL:
    """firmware/an1017/an1017.c on the runtime, built as a shared library at ``out`` (with build-time ``defines``)."""
    build_c([FIRMWARE_DIR / "an1017.c", RUNTIME_DIR / "hrt.c"], out,
            extra_flags=("-shared", "-fPIC", f"-I{FIRMWARE_DIR}", f"-I{RUNTIME_DIR}",
                         f"-DHBP_MAX_TELEMETRY={N_TELEMETRY}u", *defines))
    lib = ctypes.CDLL(str(out))
    lib.hrt_span_begin.argtypes = [ctypes.c_void_p, ctypes.c_uint8, ctypes.c_uint8, ctypes.c_uint8,
                                   ctypes.POINTER(ctypes.c_uint16), ctypes.c_uint8, ctypes.c_uint16]
    lib.hrt_span_edge.argtypes = [ctypes.c_void_p, ctypes.c_uint32, ctypes.c_uint8]
    lib.hrt_span_end.argtypes = [ctypes.c_void_p, ctypes.c_uint32]
    lib.hrt_report.argtypes = [ctypes.c_void_p, ctypes.c_uint8, ctypes.c_void_p]
    lib.an1017_param_value.restype = ctypes.c_int16
    return lib


@pytest.fixture(scope="module")
def core(tmp_path_factory, gcc: str) -> ctypes.CDLL:
    return load_core_library(tmp_path_factory.mktemp("core") / "liban1017.so")


class InProcessCore:
    """The core behind the calls the Python model's target makes (no protocol, no bridge)."""

    def __init__(self, lib: ctypes.CDLL, variant: str, period_us: int) -> None:
        self.lib = lib
        self.state = ctypes.create_string_buffer(STATE_BYTES)
        lib.an1017_init(self.state, 1 if variant == "v11" else 0)
        self.period_tcy = period_us * 20

    def step(self, s: Sensors) -> tuple:
        """One span of the runtime, as its link serves a Sensors: every edge at its time (100 ns = 2 Tcy)."""
        start = ctypes.c_uint32.from_buffer(self.state).value  # hrt_t.now, the state's first field
        pot = (ctypes.c_uint16 * 1)(s.adc[0] if s.adc else 0)
        self.lib.hrt_span_begin(self.state, s.inputs, len(s.edges), 0, pot, min(1, len(s.adc)), s.encoder)
        for time_100ns, lines in s.edges:
            offset = min(time_100ns * 2, self.period_tcy - 1)
            self.lib.hrt_span_edge(self.state, (start + offset) & 0xFFFFFFFF, lines)
        self.lib.hrt_span_end(self.state, (start + self.period_tcy) & 0xFFFFFFFF)
        o = Drive()
        self.lib.hrt_report(self.state, s.seq, ctypes.byref(o))
        return (s.seq, *o.duty, o.output_mode, o.state, o.sector, bool(o.ccw), bool(o.req_ccw), o.fault,
                tuple(o.telemetry))

    def follow(self, command: Command, model: An1017Target) -> None:
        """A scripted command, on the model and on the core alike (a write the model refuses is not
        applied: the model checks, the core applies)."""
        if command.kind == "start":
            model.start()
            self.lib.an1017_press_start(self.state)
        elif command.kind == "stop":
            if model.fw.running or model.fw.booting:
                self.lib.an1017_press_stop(self.state, 0, 0)
            model.stop()
        elif model.set_params(command.pairs).result == OK:
            self.apply(command.pairs)

    def apply(self, pairs: tuple[tuple[int, int], ...]) -> None:
        """A write the model accepted, id by id in its order, as the runtime applies one."""
        for pid, value in pairs:
            self.lib.an1017_param_set(self.state, pid, ctypes.c_int32(value))


@pytest.mark.parametrize("variant", ["seed", "v11"])
@pytest.mark.parametrize("seed,period_us", [(11, 50), (12, 250)])
def test_core_in_process_equals_python_model(core: ctypes.CDLL, variant: str, seed: int, period_us: int) -> None:
    model = An1017Target(An1017Options(variant=variant))
    model.hello(HostHello(0, PROTOCOL_VERSION, period_us, MODE_LOCKSTEP, 0))
    c = InProcessCore(core, variant, period_us)
    compared = 0
    for item in random_stream(seed, 20000, period_us):
        if isinstance(item, Command):
            c.follow(item, model)
            assert [core.an1017_param_value(c.state, i) for i in range(8)] == \
                [model.get_param(i).value for i in range(8)]
            continue
        assert c.step(item) == tuple(model.step(item)), (compared, item)
        compared += 1
    assert compared >= 20000
