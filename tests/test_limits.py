"""Issue 23: every input the bench reads has a size limit (hilbench.limits), stated in the docs.
The repros run as real processes with their memory capped: a read without a limit would end in a
MemoryError traceback there, not in the OOM killer."""

from __future__ import annotations

import os
import re
import threading
from pathlib import Path

import pytest

from _hostile import REPO_ROOT, assert_one_line_error, hilbench
from hilbench import limits
from hilbench.errors import ConfigError


def test_extends_dev_zero_is_refused_after_the_config_limit(tmp_path: Path) -> None:
    """Repro: `extends = "/dev/zero"` read until the machine's memory was gone."""
    config = tmp_path / "ext.toml"
    config.write_text('extends = "/dev/zero"\n')
    result = hilbench("run", str(config), "--no-ui", "--no-control", "--duration", "0.01")
    assert_one_line_error(result, 2, "/dev/zero", "1 MiB")


def test_scenario_dev_zero_is_refused(tmp_path: Path) -> None:
    """Repro: `--scenario /dev/zero`."""
    result = hilbench("run", "--scenario", "/dev/zero", "--target", "inprocess:an1017", "--no-ui", "--no-control",
                      "--duration", "0.01")
    assert_one_line_error(result, 2, "/dev/zero", "1 MiB")


def test_gains_file_dev_zero_is_refused() -> None:
    result = hilbench("run", "--gains-file", "/dev/zero", "--target", "inprocess:an1017", "--no-ui",
                      "--no-control", "--duration", "0.01")
    assert_one_line_error(result, 2, "/dev/zero", "1 MiB")


def test_a_large_regular_file_is_refused_before_it_is_read(tmp_path: Path) -> None:
    big = tmp_path / "big.toml"
    with big.open("wb") as handle:
        handle.truncate(limits.CONFIG_MAX_BYTES + 1)  # sparse: nothing is written, the size says it all
    from hilbench.bench.settings import load_config

    with pytest.raises(ConfigError, match=r"big.toml: 1048577 bytes, more than the limit of 1 MiB"):
        load_config(big)


def test_a_fifo_nobody_writes_to_does_not_hang(tmp_path: Path) -> None:
    """A config that extends a FIFO: opened without blocking, it reads as empty."""
    fifo = tmp_path / "pipe.toml"
    os.mkfifo(fifo)
    config = tmp_path / "c.toml"
    config.write_text(f'extends = "{fifo}"\n')
    from hilbench.bench.settings import load_config

    with pytest.raises(ConfigError, match="missing table"):
        load_config(config)


def test_a_pipe_is_read_up_to_the_limit(tmp_path: Path) -> None:
    """Process substitution (`hilbench run <(…)`) gives a pipe: it is read in pieces until its end."""
    from hilbench.bench.settings import load_config
    from hilbench.config import default_config_text

    read_fd, write_fd = os.pipe()
    text = default_config_text().encode()

    def feed() -> None:
        with os.fdopen(write_fd, "wb") as out:
            for i in range(0, len(text), 1000):
                out.write(text[i:i + 1000])
                out.flush()

    writer = threading.Thread(target=feed)
    writer.start()
    try:
        cfg = load_config(f"/proc/self/fd/{read_fd}")
    finally:
        writer.join(10)
        os.close(read_fd)
    assert cfg.link.period_us > 0


def test_every_limit_is_stated_in_the_docs() -> None:
    """docs/design.md's "Limits" section names every limit with its value."""
    text = (REPO_ROOT / "docs" / "design.md").read_text()
    section = text[text.index("## Limits"):]
    section = section[:section.find("\n## ", 5)] if "\n## " in section[5:] else section
    from hilbench.bench import control, report
    from hilbench.scope import server

    stated = {
        "CONFIG_MAX_BYTES": limits.size_text(limits.CONFIG_MAX_BYTES),
        "STORE_LINE_MAX_BYTES": limits.size_text(limits.STORE_LINE_MAX_BYTES),
        "STORE_MAX_BYTES": limits.size_text(limits.STORE_MAX_BYTES),
        "RECORDING_META_MAX_BYTES": limits.size_text(limits.RECORDING_META_MAX_BYTES),
        "RECORDING_LINE_MAX_BYTES": limits.size_text(limits.RECORDING_LINE_MAX_BYTES),
        "RECORDING_MAX_COLUMNS": str(limits.RECORDING_MAX_COLUMNS),
        "RECORDING_MAX_BYTES": limits.size_text(limits.RECORDING_MAX_BYTES),
        "MAX_FAULT_ROWS": str(report.MAX_FAULT_ROWS),
        "MAX_LINE_BYTES": limits.size_text(control.MAX_LINE_BYTES),
        "MAX_REPLY_BYTES": limits.size_text(control.MAX_REPLY_BYTES),
        "MAX_UNSENT_BYTES": limits.size_text(control.MAX_UNSENT_BYTES),
        "MAX_CONNECTIONS": str(control.MAX_CONNECTIONS),
        "MAX_STREAM_CONNECTIONS": str(control.MAX_STREAM_CONNECTIONS),
        "MAX_WS_MESSAGE": limits.size_text(server.MAX_WS_MESSAGE),
        "MAX_PAGES": str(server.MAX_PAGES),
        "HTTP_MAX_LINE": str(server.HTTP_MAX_LINE),
        "HTTP_MAX_FIELD": str(server.HTTP_MAX_FIELD),
        "HTTP_MAX_HEADERS": str(server.HTTP_MAX_HEADERS),
    }
    missing = [f"{name} ({value})" for name, value in stated.items()
               if not re.search(rf"`{name}`[^\n]*{re.escape(value)}", section)]
    assert not missing, "not stated in docs/design.md ## Limits: " + ", ".join(missing)
