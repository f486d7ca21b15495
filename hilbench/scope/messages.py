"""What a scope page may send over its WebSocket, checked in one place before any source sees it.

A page sends ``{"type": "subscribe", "columns": [NAME, ...]}`` (the columns it draws) and
``{"type": "cmd", "id": ID, "cmd": ..., ...}`` (a control command, relayed to the session, which
checks it as it checks `hilbench ctl`'s). Anything else — a message that is not a JSON object,
an unknown type, columns that are not a list of names, an id that is not a short string or
number — is answered with a refusal and the page goes on: one bad message never ends the
page's command loop (issue 23: ``{"type": "subscribe", "columns": 5}`` silenced a page).
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from typing import Any

#: the most columns a page may draw at once (the control socket's stream allows as many)
MAX_COLUMNS = 48
#: how deeply a page's message may nest lists and objects (a command's arguments are flat)
MAX_DEPTH = 16
_NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_.]{0,31}$")
#: the control commands a page may send: what its controls do, and `get` (it only reads). Not `save`
#: (it writes a file the bench's user can write, by a name the page chose), nor `stream` (the page
#: subscribes), nor `start` (the page presses S2)
PAGE_COMMANDS = ("get", "set", "ref", "load", "press", "step", "guard", "stop")


@dataclass(frozen=True)
class Subscribe:
    columns: tuple[str, ...]


@dataclass(frozen=True)
class Command:
    page_id: str | int | None
    request: dict[str, Any]  # the control request: "cmd" and its fields, without "type" and "id"


class Refused(ValueError):
    """A page message that is not one; ``page_id`` is echoed in the refusal when it was usable."""

    def __init__(self, reason: str, page_id: str | int | None = None) -> None:
        super().__init__(reason)
        self.page_id = page_id


def _page_id(value: Any) -> str | int | None:
    if isinstance(value, bool):
        return None
    if isinstance(value, int) and abs(value) < 2**53:
        return value
    if isinstance(value, str) and len(value) <= 64:
        return value
    return None


def parse_page_message(text: str) -> Subscribe | Command:
    """One WebSocket text message as a `Subscribe` or a `Command`; `Refused` with a one-line reason."""
    try:
        message = json.loads(text)
    except (ValueError, RecursionError):
        raise Refused("not a JSON message") from None
    if not isinstance(message, dict):
        raise Refused("a message must be a JSON object")
    if _depth(message) > MAX_DEPTH:  # the checks below recurse: refuse before they can overflow
        raise Refused(f"a message may nest at most {MAX_DEPTH} levels")
    kind = message.get("type")
    page_id = _page_id(message.get("id"))
    if kind == "subscribe":
        return _subscribe(message, page_id)
    if kind == "cmd":
        return _command(message, page_id)
    shown = json.dumps(kind)[:40] if _finite(kind) else "?"
    raise Refused(f"unknown message type {shown} (subscribe or cmd)", page_id)


def _subscribe(message: dict[str, Any], page_id: str | int | None) -> Subscribe:
    columns = message.get("columns")
    if not isinstance(columns, list) or len(columns) > MAX_COLUMNS or \
            not all(isinstance(c, str) and _NAME.match(c) for c in columns):
        raise Refused(f"subscribe: columns must be a list of at most {MAX_COLUMNS} column names", page_id)
    return Subscribe(tuple(columns))


def _command(message: dict[str, Any], page_id: str | int | None) -> Command:
    if "id" in message and page_id is None:
        raise Refused("cmd: id must be a short string or an integer")
    request = {k: v for k, v in message.items() if k not in ("type", "id")}
    if request.get("cmd") not in PAGE_COMMANDS:
        raise Refused(f"cmd: needs \"cmd\", one of {', '.join(PAGE_COMMANDS)} (a page's commands)", page_id)
    if not _finite(request):
        raise Refused("cmd: numbers must be finite", page_id)
    return Command(page_id, request)


def _depth(value: Any) -> int:
    """How deeply lists and objects nest in a parsed JSON value (iterative: any depth is measured)."""
    deepest, stack = 0, [(value, 1)]
    while stack:
        item, level = stack.pop()
        children = item.values() if isinstance(item, dict) else item if isinstance(item, list) else ()
        for child in children:
            if isinstance(child, (dict, list)):
                stack.append((child, level + 1))
        deepest = max(deepest, level)
    return deepest


def _finite(value: Any) -> bool:
    """No NaN or infinity anywhere (Python's JSON reads them; the control socket's JSON refuses them)."""
    if isinstance(value, float):
        return math.isfinite(value)
    if isinstance(value, dict):
        return all(_finite(v) for v in value.values())
    if isinstance(value, list):
        return all(_finite(v) for v in value)
    return True


def refusal(error: Refused, cmd: Any = None) -> dict[str, Any]:
    """The reply a page gets for a message that was refused."""
    return {"type": "reply", "id": error.page_id, "cmd": cmd if isinstance(cmd, str) else None, "ok": False,
            "message": str(error), "data": None}


__all__ = ["Command", "MAX_COLUMNS", "Refused", "Subscribe", "parse_page_message", "refusal"]
