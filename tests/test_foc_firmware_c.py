"""The FOC firmware's C source (firmware/foc) on its own: its constants against the Python
reference, both forms of the IQ24 product, and the firmware outside the CPython glue, built with
the strict flags and the sanitizers, against the Python model Drive for Drive."""

from __future__ import annotations

import random
import re
import subprocess
from pathlib import Path

import pytest

from c_build import SANITIZE_FLAGS, STRICT_FLAGS
from hilbench.protocol import HostHello, Sensors
from hilbench.targets.foc import build
from hilbench.targets.foc.firmware import FocOptions, firmware_config
from hilbench.targets.foc.iqmath import SIN_Q15_TABLE, iq, iq_mpy
from hilbench.targets.foc.target import FocTarget, available_backends

HERE = Path(__file__).resolve().parent
FOC_DIR = build.FIRMWARE_DIR


def test_config_header_defaults_are_the_servo_build():
    text = (FOC_DIR / "foc_config.h").read_text()
    header = {m.group(1).lower(): int(m.group(2)) for m in re.finditer(r"#define FOC_CFG_(\w+) (-?\d+)L?\b", text)}
    assert header == firmware_config(FocOptions())
    assert build.config_defines(FocOptions()) == ()


def test_sin_table_file_is_the_generators_output():
    import importlib.util

    spec = importlib.util.spec_from_file_location("gen_sin_table", FOC_DIR / "gen_sin_table.py")
    assert spec is not None and spec.loader is not None
    gen = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(gen)
    assert (FOC_DIR / "foc_sin_table.c").read_text() == gen.render()


@pytest.mark.skipif("c" not in available_backends(), reason="the FOC C core is not built")
def test_firmware_sine_is_the_reference_table_over_a_whole_turn():
    from hilbench.targets.foc import _core

    got = [_core.sin_q15(k) for k in range(1 << 15)]
    assert got == list(SIN_Q15_TABLE)


@pytest.mark.skipif("c" not in available_backends(), reason="the FOC C core is not built")
@pytest.mark.parametrize("base_rpm", [3000, 200, 397, 4500, 60000])
def test_speed_reference_conversion_equals_the_truncating_iq(base_rpm):
    ref = [FocTarget(FocOptions(base_rpm=base_rpm), backend=b).fw for b in ("python", "c")]
    for rpm in list(range(-3 * base_rpm - 5, 3 * base_rpm + 6, max(1, base_rpm // 997))) + [0, 1, -1]:
        for fw in ref:
            fw.set_speed_ref_rpm(rpm)
        assert ref[1].speed_ref == ref[0].speed_ref, rpm


def _edge_values() -> list[int]:
    base = [0, 1, -1, 2, -2, (1 << 24), -(1 << 24), (1 << 31) - 1, -(1 << 31), (1 << 16) - 1, 1 << 16, -(1 << 16),
            0x7FFF, -0x8000, 3750, 14529495, -14529495, 0x12345678, -0x12345678]
    return base


def test_iq24_product_forms_equal_iqmpy(gcc, tmp_path):
    rng = random.Random(3)
    edges = _edge_values()
    pairs = [(a, b) for a in edges for b in edges]
    pairs += [(rng.randint(-(1 << 31), (1 << 31) - 1), rng.randint(-(1 << 31), (1 << 31) - 1)) for _ in range(20000)]
    pairs += [(rng.randint(-(1 << 26), 1 << 26), rng.randint(-(1 << 26), 1 << 26)) for _ in range(20000)]
    text = "".join(f"{a} {b}\n" for a, b in pairs)
    want = [iq_mpy(a, b) for a, b in pairs]
    for form in ("-DIQ24_MPY_INT64=1", "-DIQ24_MPY_LIMBS=1"):
        exe = tmp_path / f"iq{form[-7:-2]}"
        cmd = [gcc, *STRICT_FLAGS, "-O1", *SANITIZE_FLAGS, form, f"-I{FOC_DIR}", str(HERE / "foc_c" / "iq24_vectors.c"),
               "-o", str(exe)]
        subprocess.run(cmd, check=True, capture_output=True, timeout=120)
        out = subprocess.run([str(exe)], input=text, capture_output=True, text=True, timeout=60, check=True)
        got = [int(x) for x in out.stdout.split()]
        assert got == want, form


def _stream(seed: int, n: int):
    """Commands and Sensors lines of a seeded stream (no plant: random codes reach every branch)."""
    rng = random.Random(seed)
    enc = 0
    for k in range(n):
        if k % 4000 == 10:
            yield ("START",)
        if k % 6100 == 5000:
            yield ("STOP",) if rng.random() < 0.5 else ("TRIP",)
        if k % 1500 == 700:
            yield ("R", rng.randint(-3300, 3300))
        if k % 2300 == 1100:
            yield ("G", rng.choice(("spd", "id", "iq")), rng.choice(("kp", "ki", "kc", "out_max")), iq(rng.random()))
        enc = (enc + rng.randint(-15, 15)) & 0xFFFF
        inputs = (0x08 if rng.random() < 0.001 else 0) | (0x40 if rng.random() < 0.01 else 0)
        adc = (rng.randint(0, 4095), rng.randint(0, 4095), rng.randint(3000, 3300))
        yield ("S", inputs, enc, adc, rng.choice((1, 1, 1, 2, 3, 0)))


def _python_drives(options: FocOptions, commands) -> list[str]:
    t = FocTarget(options, backend="python")
    t.hello(HostHello(0, 1, 50, 0, 100))
    fw = t.fw
    lines = []
    for cmd in commands:
        if cmd[0] == "S":
            _, inputs, enc, adc, halves = cmd
            s = Sensors(0, inputs, 0xFFFF, enc, adc)
            t._inputs(inputs)
            duty = t._run_halves(halves, s)
            d = t._drive(0, duty)
            fields = (*duty, d.output_mode, d.state, d.sector, int(d.direction_ccw), int(d.required_ccw), d.fault,
                      *d.telemetry)
            lines.append(" ".join(str(int(v)) for v in fields))
        elif cmd[0] == "R":
            fw.set_speed_ref_rpm(cmd[1])
        elif cmd[0] == "G":
            fw.set_gain(cmd[1], cmd[2], cmd[3])
        elif cmd[0] == "START":
            fw.start()
        elif cmd[0] == "STOP":
            fw.stop()
        else:
            fw.stop(4, 1)
    return lines


def _c_text(commands) -> str:
    out = []
    for cmd in commands:
        if cmd[0] == "S":
            _, inputs, enc, adc, halves = cmd
            out.append(f"S {inputs} {enc} {adc[0]} {adc[1]} {adc[2]} {halves}")
        else:
            out.append(" ".join(str(c) for c in cmd))
    return "\n".join(out) + "\n"


@pytest.mark.slow
@pytest.mark.parametrize("options", [
    FocOptions(align_s=0.002),
    FocOptions(align_s=0.003, pi_form="pi_clamp", speed_fr="v4.3", calibrated_angle=-1250, learn_index=False,
               align_current_a=0.0, speed_ramp_rpm_per_s=0.0, qep_signed16=True),
], ids=["servo", "options"])
def test_firmware_source_equals_the_python_model_under_sanitizers(gcc, tmp_path, options):
    exe = tmp_path / "foc_stream"
    cmd = [gcc, *STRICT_FLAGS, "-O1", *SANITIZE_FLAGS, *build.config_defines(options), f"-I{FOC_DIR}",
           str(HERE / "foc_c" / "foc_stream.c"), *(str(s) for s in build.SOURCES), "-o", str(exe)]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    commands = list(_stream(11, 40_000))
    run = subprocess.run([str(exe)], input=_c_text(commands), capture_output=True, text=True, timeout=300)
    assert run.returncode == 0 and not run.stderr, run.stderr[-2000:]
    got = run.stdout.splitlines()
    want = _python_drives(options, commands)
    assert len(got) == len(want)
    for k, (a, b) in enumerate(zip(want, got)):
        assert a == b, f"Drive {k}: python {a} != C {b}"
