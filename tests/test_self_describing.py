"""Self-describing targets (issue 27, item 4): a firmware on the runtime that no hilbench module knows
runs under `hilbench run sil:FOLDER` / `simavr:FOLDER` as is. From its handshake (TargetInfo,
TelemetryInfo, ParamInfo with units) the bench builds its profile: telemetry recorded as named
columns with units and scales, the parameters by name for `ctl`, `step` and the scenario's `set`,
the speed reference by the porting guide's convention (a read-write INT `speed_ref` in rpm).

The firmwares are firmware/template (a hall-commutated drive, the porting guide's starting point)
and firmware/tiny (tests/plugin_tiny's V/f drive in C); both build with their Makefiles
(firmware/runtime/firmware.mk), warning-free under the strict flags for the host and the AVR.
"""

from __future__ import annotations

import csv
import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from conftest import REPO_ROOT
from hilbench.protocol import PTYPE_INT, TELEMETRY_MEASURED_SPEED, ParamInfo, TelemetryInfo
from hilbench.targets.describe import Description, column_name, described_profile, speed_reference
from hilbench.targets.profile import generic_profile

CONFIG = REPO_ROOT / "bench_configs" / "hurst_mclv.toml"


def _cli(*args: str, timeout: float = 300.0) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "hilbench", *args], capture_output=True, text=True,
                          timeout=timeout, cwd=REPO_ROOT)


def _rows(path: Path) -> list[dict[str, str]]:
    return list(csv.DictReader(line for line in path.open() if not line.startswith("#")))


def _config(tmp_path: Path, target: str, scenario: str) -> Path:
    config = tmp_path / "run.toml"
    config.write_text(CONFIG.read_text() + f'\n[link]\ntarget = "{target}"\n' + scenario)
    return config


TINY_SCENARIO = """
[[scenario]]
at_s = 0.0
ref_rpm = 800.0

[[scenario]]
at_s = 0.01
press = "s2"

[[scenario]]
at_s = 0.3
set = { v_per_krpm = 38 }

[[scenario]]
at_s = 0.6
end = true
"""


# ------------------------------------------------------------------------------------- the profile

def test_column_names_and_the_reference_convention() -> None:
    assert column_name("measured_speed", "rpm") == "measured_speed_rpm"
    assert column_name("speed_rpm", "rpm") == "speed_rpm"
    assert column_name("Edge Interval", "us") == "edge_interval_us"
    assert column_name("modulation", "") == "modulation"
    p = lambda name, unit, ptype=PTYPE_INT, access=1: ParamInfo(0, 0, ptype, access, 0, 1, 0, name, unit)  # noqa: E731
    assert speed_reference((p("kp", ""), p("speed_ref", "rpm"))).param == "speed_ref"
    assert speed_reference((p("limit_rpm", "rpm"),)) is None  # not a reference by name
    assert speed_reference((p("speed_ref", "rpm", access=0),)) is None  # read-only
    assert speed_reference((p("speed_ref", "rpm", ptype=0),)) is None  # Q15: no scale to rpm known


def test_a_described_profile_names_and_scales_the_columns_and_avoids_the_benchs_names() -> None:
    telemetry = (
        TelemetryInfo(0, 0, int(TELEMETRY_MEASURED_SPEED), PTYPE_INT, 1, 1, "speed", "rpm"),
        TelemetryInfo(0, 1, 0x80, PTYPE_INT, 1, 10, "angle", "deg"),
        TelemetryInfo(0, 2, 0x81, PTYPE_INT, 1, 1, "sector", ""),
    )
    profile = described_profile(generic_profile("X"), Description(None, telemetry, ()),
                                frozenset({"speed_rpm", "sector"}))
    columns = {c.telemetry_id: c for c in profile.telemetry}
    assert columns[int(TELEMETRY_MEASURED_SPEED)].column == "fw_speed_rpm"
    assert (columns[0x80].column, columns[0x80].unit, columns[0x80].scale) == ("angle_deg", "deg", 0.1)
    assert columns[0x81].column == "fw_sector"
    assert profile.speed_column == "fw_speed_rpm"


# ------------------------------------------------------------------------------------- the firmwares

@pytest.mark.parametrize("folder", ["template", "tiny"])
def test_the_firmware_folders_build_strict_for_the_host_and_the_avr(folder: str, tmp_path: Path, gcc: str) -> None:
    work = tmp_path / folder
    shutil.copytree(REPO_ROOT / "firmware" / folder, work, ignore=shutil.ignore_patterns("build"))
    runtime = f"RUNTIME={REPO_ROOT / 'firmware' / 'runtime'}"
    goals = ["sil"] + (["avr", "check"] if shutil.which("avr-gcc") else [])
    for goal in goals:
        result = subprocess.run(["make", "-C", str(work), goal, runtime], capture_output=True, text=True, timeout=300)
        assert result.returncode == 0, result.stdout + result.stderr
        assert "warning" not in result.stderr.lower(), result.stderr


@pytest.mark.slow
def test_tiny_in_c_runs_as_sil_with_no_python_module(tmp_path: Path) -> None:
    """The V/f drive in C behaves as tests/plugin_tiny's Python one: it follows 800 rpm (accel 4000 rpm/s),
    `set` reaches its parameter, the columns carry its names, units and scales, `report` reads them."""
    out = tmp_path / "tiny.csv"
    run = _cli("run", str(_config(tmp_path, "sil:firmware/tiny", TINY_SCENARIO)), "--record", str(out), "--json",
               "--no-control", "--no-ui")
    assert run.returncode == 0, run.stderr
    summary = json.loads(run.stdout)
    assert summary["firmware"] == "TINYC" and summary["params"]["v_per_krpm"] == 38
    rows = _rows(out)
    assert {"ref_speed_rpm[rpm]", "tiny_angle_deg[deg]", "tiny_modulation"} <= set(rows[0])
    assert abs(float(rows[-1]["speed_rpm[rpm]"]) - 800.0) < 20.0
    assert float(rows[-1]["ref_speed_rpm[rpm]"]) == 800.0
    assert float(rows[-1]["tiny_modulation"]) == pytest.approx(0.040 + 0.38 * 0.8, abs=0.002)  # boost + 38 %/krpm
    report = _cli("report", str(out), "--json", "--plot", str(tmp_path / "plots"))
    assert report.returncode == 0, report.stderr


@pytest.mark.slow
def test_step_works_on_a_described_firmwares_parameters() -> None:
    step = _cli("step", "--target", "sil:firmware/tiny", "--from", "300", "--to", "600", "--settle", "0.2",
                "--after", "0.2", "--gains", "v_per_krpm=36", "--json")
    assert step.returncode == 0, step.stderr
    (row,) = json.loads(step.stdout)
    assert row["v_per_krpm"] == 36 and row["rise_time_s"] == pytest.approx(300 * 0.8 / 4000, abs=0.01)


@pytest.mark.slow
def test_the_template_measures_what_the_plant_does(tmp_path: Path) -> None:
    """The template's hall-period speed (its own telemetry, renamed fw_speed_rpm beside the plant's
    speed_rpm) follows the plant; a write its constraint refuses is refused whole."""
    out = tmp_path / "template.csv"
    scenario = """
[[scenario]]
at_s = 0.01
press = "s2"

[[scenario]]
at_s = 0.3
set = { duty_pct = 30 }

[[scenario]]
at_s = 0.8
end = true
"""
    run = _cli("run", str(_config(tmp_path, "sil:firmware/template", scenario)), "--record", str(out), "--json",
               "--no-control", "--no-ui")
    assert run.returncode == 0, run.stderr
    summary = json.loads(run.stdout)
    assert summary["firmware"] == "TEMPLATE" and summary["params"]["duty_pct"] == 30
    rows = _rows(out)
    assert {"fw_speed_rpm[rpm]", "fw_sector", "edge_interval_us[us]"} <= set(rows[0])
    plant, firmware = float(rows[-1]["speed_rpm[rpm]"]), float(rows[-1]["fw_speed_rpm[rpm]"])
    assert plant > 300.0 and abs(firmware - plant) < 0.05 * plant


@pytest.mark.slow
def test_simavr_runs_the_same_firmware_folder_bit_for_bit(tmp_path: Path) -> None:
    """`simavr:firmware/tiny`: the same source on an ATmega328P in simavr records what the SIL build
    records, column for column (lockstep: the host's clock, the same integer arithmetic)."""
    if shutil.which("avr-gcc") is None or not Path("/usr/include/simavr/sim_avr.h").is_file():
        pytest.skip("avr-gcc and libsimavr-dev are needed")
    scenario = TINY_SCENARIO.replace("at_s = 0.6\nend = true", "at_s = 0.1\nend = true")
    outs = []
    for kind in ("sil", "simavr"):
        out = tmp_path / f"{kind}.csv"
        config = _config(tmp_path, f"{kind}:firmware/tiny", scenario)
        run = _cli("run", str(config), "--record", str(out), "--no-control", "--no-ui", timeout=600)
        assert run.returncode == 0, run.stderr
        outs.append(_rows(out))
    skip = {"rtt_us[us]", "lateness_us[us]"}
    assert len(outs[0]) == len(outs[1]) == 2000
    for a, b in zip(*outs):
        assert {k: v for k, v in a.items() if k not in skip} == {k: v for k, v in b.items() if k not in skip}


def _gcc_link(tmp_path: Path, fw_defines: tuple[str, ...], runtime_defines: tuple[str, ...]) -> subprocess.CompletedProcess[str]:
    """firmware/tiny's SIL with its declaration and the runtime compiled with their own defines, linked."""
    from hilbench.targets.foc.build import STRICT_FLAGS

    runtime, proto = REPO_ROOT / "firmware" / "runtime", REPO_ROOT / "firmware_protocol"
    includes = [f"-I{d}" for d in (REPO_ROOT / "firmware" / "tiny", runtime, proto)]
    fw = subprocess.run(["gcc", *STRICT_FLAGS, *fw_defines, *includes, "-c", str(REPO_ROOT / "firmware" / "tiny" / "tiny.c"),
                         "-o", str(tmp_path / "tiny.o")], capture_output=True, text=True, timeout=120)
    assert fw.returncode == 0, fw.stderr
    core = [runtime / "hrt.c", runtime / "hrt_link.c", proto / "hbp.c", runtime / "ports" / "host" / "hrt_host.c"]
    return subprocess.run(["gcc", *STRICT_FLAGS, *runtime_defines, *includes, str(tmp_path / "tiny.o"), *map(str, core),
                           "-o", str(tmp_path / "tiny_sil")], capture_output=True, text=True, timeout=120)


def test_declarations_build_without_the_self_description_and_a_mixed_build_does_not_link(tmp_path: Path) -> None:
    """HRT_DESCRIBE=0 changes the declaration's layout: template, tiny and foc write their entries with
    HRT_PARAM/HRT_TELEMETRY and compile that way too (the strict flags, -Werror); a declaration and a
    runtime compiled with different HRT_DESCRIBE fail to link (hrt.h: the symbol carries it) instead of
    reading the entries at the wrong offsets."""
    from hilbench.targets.foc.build import FIRMWARE_DIR as FOC, STRICT_FLAGS

    if shutil.which("gcc") is None or shutil.which("make") is None:
        pytest.skip("gcc and make build the SIL firmwares")
    for folder in ("tiny", "template"):
        done = subprocess.run(["make", "-s", "-C", str(REPO_ROOT / "firmware" / folder), "sil",
                               f"BUILD={tmp_path / folder}", "DEFS=-DHRT_DESCRIBE=0"],
                              capture_output=True, text=True, timeout=300)
        assert done.returncode == 0, (folder, done.stderr)
    runtime, proto = REPO_ROOT / "firmware" / "runtime", REPO_ROOT / "firmware_protocol"
    foc = subprocess.run(["gcc", *STRICT_FLAGS, "-DHRT_DESCRIBE=0", *(f"-I{d}" for d in (FOC, runtime, proto)), "-c",
                          str(FOC / "foc_hrt.c"), "-o", str(tmp_path / "foc_hrt.o")], capture_output=True, text=True,
                         timeout=120)
    assert foc.returncode == 0, foc.stderr
    assert _gcc_link(tmp_path, ("-DHRT_DESCRIBE=0",), ("-DHRT_DESCRIBE=0",)).returncode == 0
    mixed = _gcc_link(tmp_path, ("-DHRT_DESCRIBE=0",), ())
    assert mixed.returncode != 0 and "hrt_firmware_built_with_HRT_DESCRIBE_1" in mixed.stderr, mixed.stderr
