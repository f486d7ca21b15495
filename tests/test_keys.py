"""The dashboard's command line sends typed commands through the session's control socket."""

from __future__ import annotations

import threading
from pathlib import Path

from hilbench.bench.control import ControlServer
from hilbench.ui.keys import CommandLine


def test_typed_commands_reach_the_session_and_answer_in_one_line(tmp_path: Path) -> None:
    server = ControlServer(tmp_path / "s" / "ctl.sock", publish=False)
    seen: list[dict] = []
    stop = threading.Event()

    def session() -> None:  # stands in for Session._serve_control: answers what arrives
        while not stop.is_set():
            for request in server.poll():
                seen.append({"cmd": request.cmd, **request.args})
                if request.cmd == "set" and request.args["params"].get("kp", 0) > 1:
                    request.reply(False, "kp=2 is out of range 0.00000..0.99997")
                else:
                    request.reply(True, "applied", {"params": {"kp": 0.2, "ki": 0.01, "kd": 0.0}})
            stop.wait(0.001)

    thread = threading.Thread(target=session, daemon=True)
    thread.start()
    try:
        line = CommandLine(server.path, on_message=lambda text: None)
        assert line.execute("set kp=0.2") == "> set kp=0.2: ok: applied"
        assert line.execute("set kp=2") == "> set kp=2: refused: kp=2 is out of range 0.00000..0.99997"
        assert "unknown command" in line.execute("frobnicate")
        assert line.execute(f"save {tmp_path / 'g.toml'}") == "> save " + str(tmp_path / "g.toml") + ": saved"
        assert (tmp_path / "g.toml").read_text().startswith("[target]\nkp = 0.200000")
    finally:
        stop.set()
        thread.join(timeout=5)
        server.close()
    assert seen[0] == {"cmd": "set", "params": {"kp": 0.2}}
