"""What the Python master adapters share: the JSON-lines loop of the master adapter
protocol (role "master", adapters/PROTOCOL.md), its hello, and the answers an operation
gives.

An adapter keeps what is its own library's: its operations (`op_read` and the others,
functions of the request returning the answer's fields, gathered by `ops_of`), how it opens
and closes its line, and how it maps what the library returned or raised to an answer
(`values`, `done`, `echo`, `exception`, `error`, `raised`). `serve` reads one request per
line on stdin and writes one answer per line, with the request's id, to the stream given
(the adapter's real stdout, from `protocol_stream`, which points `sys.stdout` at stderr so
that a library's prints cannot corrupt the protocol).

The loop's own answers, as the master adapters have always given them:

* a line that is not a JSON object: ``{"id": null, "ok": false, "error": "bad request: ..."}``;
* an op the adapter has no function for, or one that raises `Unsupported`:
  ``"ok": false, "error": "unsupported"`` with a ``detail`` (the gate skips the case);
* an op that raises `KeyError`, `ValueError` or `TypeError` (a field missing or not of its
  type): ``"error": "bad request: <type>: <text>"``;
* anything else an op raises (such as an operation before ``open``): logged on stderr and
  answered ``"error": "<type>: <text>"``, an ERROR of the adapter for that case only. What
  the library raised inside a call is not that: the adapter answers it as ``raised``.
"""

from __future__ import annotations

import json
import sys
from typing import Callable, Optional, TextIO

from adapter_common import Unsupported, hexs  # noqa: F401 - shared with the codec adapters

Op = Callable[[dict], dict]


def protocol_stream() -> TextIO:
    """The real stdout, for the answers; `sys.stdout` then points at stderr, so that a
    library's prints (its debug output included) can never corrupt the protocol."""
    out = sys.stdout
    sys.stdout = sys.stderr
    return out


# The protocol's operations; an adapter defines `op_<name>` (dashes as underscores) for each.
OP_NAMES = ("hello", "open", "read", "write-single", "write-multiple", "loop-back", "close")


def ops_of(namespace: dict) -> dict[str, Op]:
    """The operations an adapter's module defines (`globals()`), by protocol name; an op it
    does not define is answered "unsupported" by the loop."""
    ops = {name: namespace.get("op_" + name.replace("-", "_")) for name in OP_NAMES}
    return {name: fn for name, fn in ops.items() if fn is not None}


def closing(close: Callable[[], None]) -> Op:
    """The `close` operation of an adapter whose line `close` closes."""
    def op_close(_req: dict) -> dict:
        close()
        return {"ok": True}
    return op_close


def h4(v: int) -> str:
    """A register or value as hex4 ("0BB8")."""
    return f"{v & 0xFFFF:04X}"


def refuse_hello(req: dict) -> Optional[dict]:
    """The answer to a hello that is not protocol 1, role master; None for one that is."""
    if req.get("protocol") != 1 or req.get("role") != "master":
        return {"ok": False, "error": "this adapter speaks protocol 1, role master"}
    return None


def hello_answer(adapter: str, implementation: str, version: str, supports: list[str],
                 lines: list[str], modes: list[str]) -> dict:
    """The answer to a hello the adapter takes: who it is and what it offers."""
    return {"ok": True, "protocol": 1, "role": "master", "adapter": adapter,
            "implementation": implementation, "version": version,
            "supports": supports, "lines": lines, "modes": modes}


def values(registers) -> dict:
    """A read returned these register values (numbers)."""
    return {"ok": True, "result": "values", "values": [h4(v) for v in registers]}


def done(**extra) -> dict:
    """A write returned normally; `extra` is an `echo` (what the library returned) and/or a
    `note`."""
    return {"ok": True, "result": "done", **extra}


def echo(test_code: int, data: bytes) -> dict:
    """A loop-back returned this sub-function and data."""
    return {"ok": True, "result": "echo", "test_code": h4(test_code), "data": hexs(data)}


def exception(code: int, **extra) -> dict:
    """The library reported a Modbus exception response with this code."""
    return {"ok": True, "result": "exception", "code": f"{code:02X}", **extra}


def error(kind: str, message: str, **extra) -> dict:
    """The library reported a failure that is not an exception (`kind`: timeout, checksum,
    invalid-frame or other) with this text."""
    return {"ok": True, "result": "error", "kind": kind, "message": message, **extra}


def raised(type_name: str, message: str) -> dict:
    """The library raised something its API does not document for the call."""
    return {"ok": True, "result": "raised", "type": type_name, "message": message}


def handle(req: dict, ops: dict[str, Op], adapter: str) -> dict:
    """One request (a JSON object) to its answer, with the request's id."""
    fn = ops.get(req.get("op"))
    try:
        answer = fn(req) if fn else {"ok": False, "error": "unsupported",
                                     "detail": f"op {req.get('op')!r}"}
    except Unsupported as exc:
        answer = {"ok": False, "error": "unsupported", "detail": str(exc)}
    except (KeyError, ValueError, TypeError) as exc:
        answer = {"ok": False, "error": f"bad request: {type(exc).__name__}: {exc}"}
    except Exception as exc:  # noqa: BLE001 - the adapter failed: an ERROR for this case
        print(f"[{adapter}] id={req.get('id')}: {type(exc).__name__}: {exc}", file=sys.stderr,
              flush=True)
        answer = {"ok": False, "error": f"{type(exc).__name__}: {exc}"}
    return {"id": req.get("id"), **answer}


def serve(ops: dict[str, Op], adapter: str, out: TextIO,
          at_end: Optional[Callable[[], None]] = None) -> int:
    """The protocol's loop over stdin: exit code 0. When stdin ends (the gate is done),
    `at_end` runs (to close what the adapter has open); when the gate goes away (its end of
    stdout is closed), the loop returns at once."""
    for raw in sys.stdin.buffer:
        line = raw.decode("utf-8", "replace").strip()
        if not line:
            continue
        try:
            req = json.loads(line)
            if not isinstance(req, dict):
                raise ValueError("not a JSON object")
        except ValueError as exc:
            answer = {"id": None, "ok": False, "error": f"bad request: {exc}"}
        else:
            answer = handle(req, ops, adapter)
        try:
            out.write(json.dumps(answer, separators=(",", ":")) + "\n")
            out.flush()
        except BrokenPipeError:
            return 0
    if at_end is not None:
        at_end()
    return 0
