"""Compile the C protocol library and its test programs with the strict flags the issue requires."""

from __future__ import annotations

import shutil
import subprocess
from collections.abc import Iterable, Sequence
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
FIRMWARE_DIR = REPO / "firmware_protocol"
STRICT_FLAGS = ("-std=c99", "-pedantic", "-Wall", "-Wextra", "-Wconversion", "-Werror")
SANITIZE_FLAGS = ("-fsanitize=address,undefined", "-fno-sanitize-recover=all", "-fno-omit-frame-pointer", "-g")
LIBRARY_SOURCES = (FIRMWARE_DIR / "hbp.c", FIRMWARE_DIR / "hbp_codec.c", FIRMWARE_DIR / "hbp_messages.c",
                   FIRMWARE_DIR / "hbp_params.c")


def build_c(sources: Iterable[Path | str], output: Path | str, extra_flags: Sequence[str] = (),
            sanitize: bool = False) -> Path:
    """Compile and link `sources` into `output`; raises AssertionError with gcc's output on failure."""
    gcc = shutil.which("gcc")
    if gcc is None:
        raise FileNotFoundError("gcc not found on PATH")
    out = Path(output)
    cmd = [gcc, *STRICT_FLAGS, "-O1", f"-I{FIRMWARE_DIR}", *(SANITIZE_FLAGS if sanitize else ()),
           *extra_flags, *(str(s) for s in sources), "-o", str(out)]
    result = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    if result.returncode != 0:
        raise AssertionError(f"gcc failed ({' '.join(cmd)}):\n{result.stdout}{result.stderr}")
    return out
