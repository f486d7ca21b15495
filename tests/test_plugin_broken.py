"""A broken target plug-in is left out, named, and never breaks the built-in targets (repro: one
whose factory raised gave a traceback in every command, even `run --target inprocess:an1017`)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

ENTRIES = {  # entry point -> object, and what `hilbench targets` says of it
    "boom": ("plug_mod:boom", "cannot load: RuntimeError: factory exploded"),
    "bad": ("plug_mod:bad_name", "target profile 'Bad-Name': names are lowercase identifiers"),
    "hijack": ("plug_mod:hijack", "its name 'an1017' is a built-in target's, which it may not replace"),
    "number": ("plug_mod:NOT_A_PROFILE", "not a TargetProfile"),
    "missing": ("no_such_module:x", "cannot load: ModuleNotFoundError"),
}

MODULE = '''
import dataclasses
from hilbench.targets.loopback import PROFILE
def boom():
    raise RuntimeError("factory exploded")
def bad_name():
    return dataclasses.replace(PROFILE, name="Bad-Name")
def hijack():
    return dataclasses.replace(PROFILE, name="an1017")
NOT_A_PROFILE = 42
'''


def _hilbench(folder: Path, *args: str) -> subprocess.CompletedProcess[str]:
    env = dict(os.environ, PYTHONPATH=os.pathsep.join(filter(None, (str(folder), os.environ.get("PYTHONPATH")))))
    return subprocess.run([sys.executable, "-m", "hilbench", *args], capture_output=True, text=True, timeout=120,
                          env=env, cwd=folder)


def test_broken_plugins_are_left_out_named_and_the_built_ins_still_run(tmp_path: Path) -> None:
    (tmp_path / "plug_mod.py").write_text(MODULE)
    info = tmp_path / "brokenplug-0.1.dist-info"
    info.mkdir()
    (info / "METADATA").write_text("Metadata-Version: 2.1\nName: brokenplug\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(
        "[hilbench.targets]\n" + "".join(f"{name} = {value}\n" for name, (value, _) in ENTRIES.items()))
    listed = _hilbench(tmp_path, "targets")
    assert listed.returncode == 0 and "Traceback" not in listed.stderr, listed.stderr
    for name, (value, why) in ENTRIES.items():
        assert f"left out: target plug-in {name!r} ({value}): {why}" in listed.stderr, listed.stderr
    assert "an1017" in listed.stdout and "loopback" in listed.stdout
    run = _hilbench(tmp_path, "run", "--target", "inprocess:an1017", "--duration", "0.02", "--no-ui", "--no-control")
    assert run.returncode == 0, run.stderr  # the built-in, not the plug-in that took its name
    asked = _hilbench(tmp_path, "run", "--target", "inprocess:boom", "--duration", "0.02", "--no-ui", "--no-control")
    assert asked.returncode == 2 and "Traceback" not in asked.stderr, asked.stderr
    assert asked.stderr.strip().splitlines()[-1].endswith(
        "target plug-in 'boom' (plug_mod:boom): cannot load: RuntimeError: factory exploded"), asked.stderr
