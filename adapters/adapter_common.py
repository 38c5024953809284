"""What the Python gate adapters share: the request errors, the field readers, and the
JSON-lines loop of the gate protocol (adapters/PROTOCOL.md).

An adapter keeps its own operations (`OPS`: op name -> function of the request, returning
the answer's fields) and its own log; `serve` reads one request per line on stdin and
writes one answer per line, with the request's id, to the stream given (the adapter's
real stdout: adapters point `sys.stdout` at stderr so that a library's prints cannot
corrupt the protocol).
"""

from __future__ import annotations

import json
import sys
from typing import Callable, TextIO


class Unsupported(Exception):
    """The library cannot express the operation: the gate skips the case."""


class BadRequest(Exception):
    """The gate's request is malformed."""


def parse_hex(text) -> bytes:
    """Bytes from space-separated hex pairs ("01 03 00 10")."""
    if not isinstance(text, str):
        raise BadRequest("expected a hex string")
    try:
        return bytes(int(t, 16) for t in text.split())
    except ValueError:
        raise BadRequest(f"bad hex {text!r}") from None


def hexs(data: bytes) -> str:
    """Bytes as upper-case hex pairs separated by spaces."""
    return " ".join(f"{b:02X}" for b in data)


def hexnum(fields: dict, key: str) -> int:
    """A hex number field ("2520H" or "2520")."""
    value = fields.get(key)
    if not isinstance(value, str):
        raise BadRequest(f"field {key!r} missing or not hex")
    try:
        return int(value.rstrip("Hh"), 16)
    except ValueError:
        raise BadRequest(f"field {key!r}: bad hex {value!r}") from None


def num(fields: dict, key: str) -> int:
    """An integer field (a JSON bool is not one)."""
    value = fields.get(key)
    if isinstance(value, bool) or not isinstance(value, int):
        raise BadRequest(f"field {key!r} missing or not a number")
    return value


Op = Callable[[dict], dict]

# The version of adapters/PROTOCOL.md the codec adapters speak.
PROTOCOL = 1


def hello(req: dict, adapter: str, implementation: str, version: str, supports: list[str]) -> dict:
    """The answer to the gate's hello: who the adapter is and what it supports; a refusal
    where the gate speaks another protocol."""
    if req.get("protocol") != PROTOCOL:
        return {"ok": False, "error": f"protocol {req.get('protocol')!r} not spoken; this adapter speaks {PROTOCOL}"}
    return {
        "ok": True,
        "protocol": PROTOCOL,
        "adapter": adapter,
        "implementation": implementation,
        "version": version,
        "supports": supports,
    }


def crc16(data: bytes) -> bytes:
    """CRC-16/MODBUS of `data`, low byte first: only to build the frames an adapter or a
    script sends itself, never to judge one (the gate judges with its own)."""
    crc = 0xFFFF
    for b in data:
        crc ^= b
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return bytes([crc & 0xFF, crc >> 8])


def handle(line: str, ops: dict[str, Op], log: Callable[[str], None], raised: str = "") -> dict:
    """One request line to one answer. An exception the operation did not expect is an
    ERROR for this case only (logged), with `raised` before its name."""
    try:
        req = json.loads(line)
    except ValueError as exc:
        return {"id": None, "ok": False, "error": f"bad request: not JSON ({exc})"}
    if not isinstance(req, dict):
        return {"id": None, "ok": False, "error": "bad request: not a JSON object"}
    fn = ops.get(req.get("op"))
    try:
        if fn is None:
            answer = {"ok": False, "error": "unsupported", "detail": f"op {req.get('op')!r}"}
        else:
            answer = fn(req)
    except Unsupported as exc:
        answer = {"ok": False, "error": "unsupported", "detail": str(exc)}
    except BadRequest as exc:
        answer = {"ok": False, "error": f"bad request: {exc}"}
    except Exception as exc:  # noqa: BLE001 - the library failed: an ERROR for this case
        log(f"id={req.get('id')} {req.get('op')}: {type(exc).__name__}: {exc}")
        answer = {"ok": False, "error": f"{raised}{type(exc).__name__}: {exc}"}
    return {"id": req.get("id"), **answer}


def serve(ops: dict[str, Op], log: Callable[[str], None], out: TextIO, raised: str = "") -> int:
    """The protocol's loop over stdin until it ends (or the gate goes away): exit code 0."""
    for raw in sys.stdin.buffer:
        line = raw.decode("utf-8", errors="replace").strip()
        if not line:
            continue
        try:
            out.write(json.dumps(handle(line, ops, log, raised), separators=(",", ":")) + "\n")
            out.flush()
        except BrokenPipeError:
            return 0
    return 0
