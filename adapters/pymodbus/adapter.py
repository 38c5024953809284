#!/usr/bin/env python3
"""Conformance-gate adapter for pymodbus (protocol 1, see ../PROTOCOL.md).

Reads one JSON request per line on stdin, writes one JSON answer per line on
stdout (flushed after every line). Logs go to stderr only.

Every decision about a frame is pymodbus's own:

* decode: ``FramerRTU`` / ``FramerAscii`` built on ``DecodePDU(is_server=...)``,
  fed the whole frame through ``framer.handleFrame(data, 0, 0)`` (the call the
  pymodbus transaction manager makes on received bytes). The resulting PDU
  object is mapped to the protocol's message JSON.
* encode: the pymodbus PDU class registered for the function code and
  direction (``DecodePDU.pdu_table`` / ``pdu_sub_table``), instantiated with the
  message fields and framed with ``framer.buildFrame(pdu)``.
* crc: ``FramerRTU.compute_CRC`` (pymodbus returns the wire order, low byte
  first, as a big-endian int; the adapter swaps it to give the CRC value).
* lrc: ``FramerAscii.compute_LRC``.

The adapter does not check checksums, lengths or layouts itself: what pymodbus
accepts is reported as accepted, even where that is wrong.

Set PYMODBUS_ADAPTER_DEBUG=1 to copy pymodbus's own debug log to stderr.
"""

from __future__ import annotations

import json
import logging
import os
import re
import struct
import sys

# The script's directory holds nothing to import; keep it from shadowing
# anything (e.g. a stray logging.py).
if sys.path and os.path.abspath(sys.path[0] or ".") == os.path.dirname(
    os.path.abspath(__file__)
):
    del sys.path[0]

import pymodbus  # noqa: E402
from pymodbus.exceptions import ModbusException  # noqa: E402
from pymodbus.framer import FramerAscii, FramerRTU  # noqa: E402
from pymodbus.logging import Log  # noqa: E402
from pymodbus.pdu import DecodePDU, ExceptionResponse  # noqa: E402
from pymodbus.pdu.diag_message import DiagnosticBase  # noqa: E402
from pymodbus.pdu.register_message import (  # noqa: E402
    ReadHoldingRegistersRequest,
    ReadHoldingRegistersResponse,
    WriteMultipleRegistersRequest,
    WriteMultipleRegistersResponse,
    WriteSingleRegisterResponse,
)

# The hello the Python adapters share (adapters/adapter_common.py); appended, so that this
# folder's neighbours never shadow an installed package.
sys.path.append(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from adapter_common import hello  # noqa: E402

ADAPTER = "pymodbus-adapter"

# Keep the real stdout for answers; anything else printing goes to stderr.
_OUT = sys.stdout
sys.stdout = sys.stderr


def log(msg: str) -> None:
    """Log a line to stderr."""
    sys.stderr.write(f"[pymodbus-adapter] {msg}\n")
    sys.stderr.flush()


class Unsupported(Exception):
    """pymodbus cannot do what was asked: answered as "unsupported"."""


class BadRequest(Exception):
    """The request itself is malformed."""


# --------------------------------------------------------------------------
# Capturing pymodbus's log, to give the reason of a rejected frame.
# --------------------------------------------------------------------------


class _Capture(logging.Handler):
    def __init__(self) -> None:
        super().__init__(logging.DEBUG)
        self.records: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        try:
            self.records.append(record.getMessage())
        except Exception:  # pragma: no cover - never let logging kill us
            pass


_CAPTURE = _Capture()
_PMLOG = logging.getLogger("pymodbus.logging")
_PMLOG.addHandler(_CAPTURE)
_PMLOG.setLevel(logging.DEBUG)
_PMLOG.propagate = False
if os.environ.get("PYMODBUS_ADAPTER_DEBUG"):
    _h = logging.StreamHandler(sys.stderr)
    _h.setFormatter(logging.Formatter("[pymodbus] %(levelname)s %(message)s"))
    _PMLOG.addHandler(_h)

_HEXDUMP = re.compile(r"(?:\s*0x[0-9a-fA-F]+)+")


def _begin_capture() -> None:
    _CAPTURE.records.clear()
    # pymodbus's Log collapses a repeated message into "Repeating....";
    # reset it so each decode gets its own, full messages.
    Log.last_log_text = ""
    Log.repeat_log = False


def _captured_reason() -> str:
    parts = []
    for text in _CAPTURE.records:
        if text.startswith("Processing:") or text.startswith("decoded PDU"):
            continue
        text = _HEXDUMP.sub("", text).strip()
        if text and text not in parts:
            parts.append(text)
    return "; ".join(parts)


# --------------------------------------------------------------------------
# Hex helpers
# --------------------------------------------------------------------------


def parse_hex_bytes(text) -> bytes:
    if not isinstance(text, str):
        raise BadRequest(f"expected a hex string, got {type(text).__name__}")
    out = bytearray()
    for tok in text.split():
        if len(tok) != 2:
            raise BadRequest(f"bad hex byte {tok!r}")
        try:
            out.append(int(tok, 16))
        except ValueError:
            raise BadRequest(f"bad hex byte {tok!r}") from None
    return bytes(out)


def hex_bytes(data: bytes) -> str:
    return " ".join(f"{b:02X}" for b in data)


def parse_hexnum(value, width: int, what: str) -> int:
    """A hex2/hex4 field (a number is also taken as its value)."""
    if isinstance(value, bool):
        raise BadRequest(f"{what}: expected hex, got {value!r}")
    if isinstance(value, int):
        n = value
    elif isinstance(value, str):
        s = value.strip()
        if s[-1:] in ("H", "h"):
            s = s[:-1]
        try:
            n = int(s, 16)
        except ValueError:
            raise BadRequest(f"{what}: bad hex {value!r}") from None
    else:
        raise BadRequest(f"{what}: expected hex, got {value!r}")
    if not 0 <= n < (1 << (8 * width)):
        raise BadRequest(f"{what}: {value!r} out of range")
    return n


def parse_number(value, what: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise BadRequest(f"{what}: expected a number, got {value!r}")
    return value


def field(fields: dict, name: str):
    if name not in fields:
        raise BadRequest(f"message field {name!r} missing")
    return fields[name]


# --------------------------------------------------------------------------
# pymodbus objects
# --------------------------------------------------------------------------


def make_framer(mode, direction):
    if direction not in ("request", "response"):
        raise BadRequest(f"bad direction {direction!r}")
    decoder = DecodePDU(is_server=(direction == "request"))
    if mode == "rtu":
        return FramerRTU(decoder)
    if mode == "ascii":
        return FramerAscii(decoder)
    raise BadRequest(f"bad mode {mode!r}")


def diag_data(message) -> bytes:
    """The data bytes of a DiagnosticBase, as pymodbus stores them."""
    if message is None:
        return b""
    if isinstance(message, (bytes, bytearray)):
        return bytes(message)
    if isinstance(message, int):
        return struct.pack(">H", message)
    if isinstance(message, (list, tuple)):
        return b"".join(struct.pack(">H", v) for v in message)
    raise TypeError(f"unknown diagnostic message type {type(message).__name__}")


def pdu_to_message(pdu) -> dict:
    """Map a decoded pymodbus PDU to the protocol's message JSON."""
    msg = {"address": f"{pdu.dev_id:02X}", "function": f"{pdu.function_code:02X}"}
    if isinstance(pdu, ExceptionResponse):
        kind = "exception"
        fields = {
            "exception_function": f"{pdu.function_code & 0x7F:02X}",
            "code": f"{pdu.exception_code:02X}",
        }
    elif isinstance(pdu, ReadHoldingRegistersRequest):
        kind = "read-request"
        fields = {"start": f"{pdu.address:04X}", "count": pdu.count}
    elif isinstance(pdu, ReadHoldingRegistersResponse):
        kind = "read-response"
        # pymodbus keeps no byte count for a read response, only the values
        # it extracted; it would send 2 * len(values).
        fields = {
            "byte_count": 2 * len(pdu.registers),
            "values": [f"{v:04X}" for v in pdu.registers],
        }
    elif isinstance(pdu, WriteSingleRegisterResponse):  # request subclasses it
        kind = "write-single"
        fields = {
            "register": f"{pdu.address:04X}",
            "value": f"{pdu.registers[0]:04X}" if pdu.registers else None,
        }
    elif isinstance(pdu, DiagnosticBase):
        kind = "loop-back"
        fields = {
            "test_code": f"{pdu.sub_function_code:04X}",
            "data": hex_bytes(diag_data(pdu.message)),
        }
    elif isinstance(pdu, WriteMultipleRegistersRequest):
        kind = "write-multiple-request"
        byte_count = pdu.byte_count if pdu.byte_count is not None else 2 * pdu.count
        fields = {
            "start": f"{pdu.address:04X}",
            "count": pdu.count,
            "byte_count": byte_count,
            "values": [f"{v:04X}" for v in pdu.registers],
        }
    elif isinstance(pdu, WriteMultipleRegistersResponse):
        kind = "write-multiple-response"
        fields = {"start": f"{pdu.address:04X}", "count": pdu.count}
    else:
        kind = "other"
        try:
            fields = {"data": hex_bytes(pdu.encode())}
        except Exception:  # pymodbus could not re-encode it
            fields = {}
    msg["kind"] = kind
    msg["fields"] = fields
    return msg


# kind -> the pymodbus base class with that layout
KIND_CLASS = {
    "read-request": ReadHoldingRegistersRequest,
    "read-response": ReadHoldingRegistersResponse,
    "write-single": WriteSingleRegisterResponse,
    "loop-back": DiagnosticBase,
    "write-multiple-request": WriteMultipleRegistersRequest,
    "write-multiple-response": WriteMultipleRegistersResponse,
}


def message_to_pdu(message, direction):
    """Build the pymodbus PDU object for a protocol message."""
    if not isinstance(message, dict):
        raise BadRequest("message must be an object")
    address = parse_hexnum(field(message, "address"), 1, "address")
    function = parse_hexnum(field(message, "function"), 1, "function")
    kind = field(message, "kind")
    fields = message.get("fields") or {}
    if not isinstance(fields, dict):
        raise BadRequest("fields must be an object")
    inx = 0 if direction == "request" else 1

    if kind == "exception":
        exc_fn = parse_hexnum(field(fields, "exception_function"), 1, "exception_function")
        code = parse_hexnum(field(fields, "code"), 1, "code")
        if function != (exc_fn | 0x80):
            # ExceptionResponse always sends exception_function | 80H.
            raise Unsupported(
                f"function {function:02X} is not exception_function {exc_fn:02X} | 80H"
            )
        return ExceptionResponse(exc_fn, exception_code=code, device_id=address)

    base = KIND_CLASS.get(kind)
    if base is None:
        raise Unsupported(f"kind {kind!r}")
    cls = DecodePDU.pdu_table.get(function, (None, None))[inx]
    if cls is None or not issubclass(cls, base):
        raise Unsupported(
            f"pymodbus has no {direction} class of layout {kind} for function {function:02X}"
        )

    if kind in ("read-request", "write-multiple-response"):
        start = parse_hexnum(field(fields, "start"), 2, "start")
        count = parse_number(field(fields, "count"), "count")
        pdu = cls(dev_id=address, address=start, count=count)
        pdu.count = count
        return pdu
    if kind == "read-response":
        values = [parse_hexnum(v, 2, "values") for v in field(fields, "values")]
        if "byte_count" in fields:
            byte_count = parse_number(fields["byte_count"], "byte_count")
            if byte_count != 2 * len(values):
                raise Unsupported(
                    f"pymodbus always sends byte_count = 2 * len(values) = {2 * len(values)}, "
                    f"not {byte_count}"
                )
        return cls(dev_id=address, registers=values)
    if kind == "write-single":
        register = parse_hexnum(field(fields, "register"), 2, "register")
        value = parse_hexnum(field(fields, "value"), 2, "value")
        return cls(dev_id=address, address=register, registers=[value])
    if kind == "loop-back":
        test_code = parse_hexnum(field(fields, "test_code"), 2, "test_code")
        data = parse_hex_bytes(fields.get("data", ""))
        sub = DecodePDU.pdu_sub_table.get(function, {}).get(test_code, (None, None))[inx]
        if sub is not None:
            return sub(message=data, dev_id=address)
        pdu = DiagnosticBase(message=data, dev_id=address)
        pdu.sub_function_code = test_code
        return pdu
    if kind == "write-multiple-request":
        start = parse_hexnum(field(fields, "start"), 2, "start")
        values = [parse_hexnum(v, 2, "values") for v in field(fields, "values")]
        count = parse_number(fields.get("count", len(values)), "count")
        if "byte_count" in fields:
            byte_count = parse_number(fields["byte_count"], "byte_count")
            if byte_count != 2 * count:
                raise Unsupported(
                    f"pymodbus always sends byte_count = 2 * count = {2 * count}, not {byte_count}"
                )
        pdu = cls(dev_id=address, address=start, registers=values, count=count)
        pdu.count = count
        return pdu
    raise Unsupported(f"kind {kind!r}")  # pragma: no cover


# --------------------------------------------------------------------------
# Operations
# --------------------------------------------------------------------------


def op_hello(req):
    return hello(req, ADAPTER, "pymodbus", pymodbus.__version__, ["decode", "encode", "crc", "lrc"])


def op_decode(req):
    framer = make_framer(req.get("mode"), req.get("direction"))
    data = parse_hex_bytes(req.get("frame"))
    _begin_capture()
    try:
        used, pdu = framer.handleFrame(data, 0, 0)
    except ModbusException as exc:
        # pymodbus's own rejection: the framer found a frame whose PDU the
        # decoder refused ("Unable to decode request").
        reason = str(exc)
        extra = _captured_reason()
        return {"ok": True, "accepted": False, "reason": f"pymodbus: {reason}" + (f" ({extra})" if extra else "")}
    except Exception as exc:  # noqa: BLE001 - the framer itself raised on the bytes
        # Not a graceful rejection: a receive loop that does not catch this stops.
        # The protocol's "raised" says so, and the gate reports it.
        return {
            "ok": True,
            "accepted": False,
            "raised": True,
            "reason": f"pymodbus's framer raised {type(exc).__name__}: {exc}",
        }
    if pdu is None:
        reason = _captured_reason() or "no frame found"
        return {
            "ok": True,
            "accepted": False,
            "reason": f"pymodbus framer gave no PDU ({used} of {len(data)} bytes consumed): {reason}",
        }
    if used != len(data):
        log(
            f"decode id={req.get('id')}: pymodbus handed a PDU to the application after "
            f"consuming {used} of {len(data)} bytes; the rest stays in its buffer"
        )
    return {"ok": True, "accepted": True, "message": pdu_to_message(pdu)}


def op_encode(req):
    direction = req.get("direction")
    framer = make_framer(req.get("mode"), direction)
    pdu = message_to_pdu(req.get("message"), direction)
    frame = framer.buildFrame(pdu)
    return {"ok": True, "frame": hex_bytes(frame)}


def op_crc(req):
    data = parse_hex_bytes(req.get("data"))
    wire = FramerRTU.compute_CRC(data)  # wire order (low byte first) as big-endian int
    value = ((wire & 0xFF) << 8) | (wire >> 8)
    return {"ok": True, "crc": f"{value:04X}"}


def op_lrc(req):
    data = parse_hex_bytes(req.get("data"))
    return {"ok": True, "lrc": f"{FramerAscii.compute_LRC(data):02X}"}


OPS = {
    "hello": op_hello,
    "decode": op_decode,
    "encode": op_encode,
    "crc": op_crc,
    "lrc": op_lrc,
}


def handle(line: str) -> dict:
    try:
        req = json.loads(line)
    except ValueError as exc:
        log(f"not JSON, answered with id null: {line[:200]!r}")
        return {"id": None, "ok": False, "error": f"bad request: not JSON ({exc})"}
    if not isinstance(req, dict):
        return {"id": None, "ok": False, "error": "bad request: not a JSON object"}
    rid = req.get("id")
    op = req.get("op")
    fn = OPS.get(op)
    try:
        if fn is None:
            log(f"unsupported op {op!r}")
            answer = {"ok": False, "error": "unsupported"}
        else:
            answer = fn(req)
    except Unsupported as exc:
        log(f"id={rid} {op}: unsupported: {exc}")
        answer = {"ok": False, "error": "unsupported"}
    except BadRequest as exc:
        answer = {"ok": False, "error": f"bad request: {exc}"}
    except Exception as exc:  # pymodbus (or we) raised: an ERROR for this case
        log(f"id={rid} {op}: {type(exc).__name__}: {exc}")
        answer = {"ok": False, "error": f"{type(exc).__name__}: {exc}"}
    return {"id": rid, **answer}


def main() -> int:
    stdin = sys.stdin.buffer
    while True:
        try:
            raw = stdin.readline()
        except KeyboardInterrupt:
            return 0
        if not raw:
            return 0
        line = raw.decode("utf-8", errors="replace").strip()
        if not line:
            continue  # blank lines are ignored
        answer = handle(line)
        try:
            _OUT.write(json.dumps(answer, separators=(",", ":")) + "\n")
            _OUT.flush()
        except BrokenPipeError:
            return 0


if __name__ == "__main__":
    try:
        sys.exit(main())
    except KeyboardInterrupt:
        sys.exit(0)
