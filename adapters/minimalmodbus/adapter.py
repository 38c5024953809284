#!/usr/bin/env python3
"""Conformance-gate adapter for minimalmodbus (protocol 1, see ../PROTOCOL.md).

minimalmodbus is a Modbus master (client) only. Every decision about a frame
is minimalmodbus's own, through the module-level functions its Instrument
uses on every transaction (underscore names: not public API, but unchanged
in signature and behaviour since 1.0; the README says which):

* decode, response: ``_extract_payload(response, slaveaddress, mode,
  functioncode)`` (checksum, address, slave exception and function code),
  then ``_parse_payload(...)`` with the arguments ``Instrument`` passes for
  ``read_registers`` / ``write_register`` / ``write_registers`` (byte count,
  data length, echoed address, value and count).
* encode, request: ``_create_payload(...)`` then ``_embed_payload(...)``,
  as ``Instrument._generic_command`` does.
* crc: ``_calculate_crc``; lrc: ``_calculate_lrc``.

minimalmodbus's master parses a response against the request it sent. The
adapter plays that request from the frame itself: the address and function
of the frame, for 03H the register count the byte count stands for (at least
1, the least minimalmodbus can ask), for 06H and 10H the address, value and
count the frame echoes. So a frame is accepted exactly when it would be a
valid answer to some request minimalmodbus can send.

Not expressible (answered "unsupported", the gate skips): decoding requests
(minimalmodbus never receives one), encoding responses (it never sends one),
and 08H in every operation (minimalmodbus has no loop-back).
"""

from __future__ import annotations

import json
import os
import sys

if sys.path and os.path.abspath(sys.path[0] or ".") == os.path.dirname(
    os.path.abspath(__file__)
):
    del sys.path[0]

import minimalmodbus as mm  # noqa: E402

# A deliberately broken variant, to show the gate catching it (conformance/tests/gate.rs):
# with MINIMALMODBUS_ADAPTER_BREAK=accept-bad-checksum every received frame's CRC or LRC
# is replaced by the right one before minimalmodbus sees it.
BREAK = os.environ.get("MINIMALMODBUS_ADAPTER_BREAK", "")
_OUT = sys.stdout
sys.stdout = sys.stderr

# The helpers and the protocol loop the Python adapters share (adapters/adapter_common.py);
# appended, so that this folder's neighbours never shadow an installed package.
sys.path.append(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from adapter_common import BadRequest, Unsupported, hello, hexnum, hexs, num, parse_hex, serve  # noqa: E402,F401


def log(msg: str) -> None:
    sys.stderr.write(f"[minimalmodbus-adapter] {msg}\n")
    sys.stderr.flush()


def word(b: bytes) -> int:
    return int(mm._two_bytes_to_num(b))


# --------------------------------------------------------------------------


def mend_checksum(mode: str, frame: bytes) -> bytes:
    """The broken variant's fault: the frame with the checksum its bytes should carry."""
    try:
        if mode == "rtu" and len(frame) >= 4:
            return frame[:-2] + mm._calculate_crc(frame[:-2])
        if mode == "ascii" and len(frame) >= 7 and frame.endswith(b"\r\n"):
            body = mm._hexdecode(frame[1:-4])
            return frame[:-4] + mm._hexencode(mm._calculate_lrc(body)) + b"\r\n"
    except (TypeError, ValueError):
        pass
    return frame


def op_hello(req):
    adapter = "minimalmodbus-adapter" + (f" (broken: {BREAK})" if BREAK else "")
    return hello(req, adapter, "minimalmodbus", mm.__version__, ["decode", "encode", "crc", "lrc"])


def master_side(req, direction: str, verb: str, other: str) -> str:
    """The request's mode, where it asks for the one direction a master handles
    (`direction`); the other (`verb`, `other`) is unsupported."""
    mode = req.get("mode")
    if mode not in ("rtu", "ascii"):
        raise BadRequest(f"bad mode {mode!r}")
    if req.get("direction") != direction:
        raise Unsupported(f"minimalmodbus is a master only: it never {verb} {other}")
    return mode


def op_decode(req):
    mode = master_side(req, "response", "decodes", "a request")
    frame = parse_hex(req.get("frame"))
    # Which request this frame answers: address and function from its first bytes
    # (as characters in ASCII). Where those cannot be read, minimalmodbus's own
    # checks decide with the TECO read request as the request sent.
    body = frame
    if mode == "ascii":
        try:
            body = bytes.fromhex(frame[1:5].decode("ascii")) if len(frame) >= 5 else b""
        except ValueError:
            body = b""
    address = body[0] if len(body) >= 1 else 1
    function = body[1] & 0x7F if len(body) >= 2 else 3
    if function == 0x08:
        raise Unsupported("minimalmodbus has no 08H (loop-back)")
    if function not in (0x03, 0x06, 0x10):
        raise Unsupported(f"minimalmodbus never sends function {function:02X}H in this protocol's kinds")
    # The request minimalmodbus would have sent, and so how many bytes its
    # Instrument reads (serial.read(n) with n from _predict_response_size):
    # bytes past n stay unread, a shorter frame is all it gets at the timeout.
    plain = body
    if mode == "ascii":
        try:
            plain = bytes.fromhex(frame[1:-2].decode("ascii"))
        except ValueError:
            plain = body
    REG = mm._Payloadformat
    if function == 0x03:
        count = max(1, (plain[2] if len(plain) > 2 and not plain[1] & 0x80 else 2) // 2)
        if count > mm._MAX_NUMBER_OF_REGISTERS_TO_READ:
            return {"ok": True, "accepted": False,
                    "reason": f"a 03H response of {count} registers answers no request minimalmodbus can send (read_registers: 1..125)"}
        sent = mm._create_payload(3, 0, None, 0, count, 0, False, 0, REG.REGISTERS)
    elif function == 0x06:
        sent = mm._create_payload(6, 0, 0, 0, 1, 0, False, 0, REG.REGISTER)
    else:
        sent = mm._create_payload(16, 0, [0], 0, 1, 0, False, 0, REG.REGISTERS)
    frame = frame[: mm._predict_response_size(mode, function, sent)]
    if BREAK == "accept-bad-checksum":
        frame = mend_checksum(mode, frame)
    try:
        payload = mm._extract_payload(frame, address, mode, function)
    except mm.SlaveReportedException as exc:
        # minimalmodbus checked the checksum, address and the exception bit; the code
        # is the byte after the function (it keeps only a message per code).
        got = frame if mode == "rtu" else bytes.fromhex(frame[1:-2].decode("ascii"))
        return {
            "ok": True,
            "accepted": True,
            "note": f"minimalmodbus raised {type(exc).__name__}: {exc}",
            "message": {
                "address": f"{got[0]:02X}",
                "function": f"{got[1]:02X}",
                "kind": "exception",
                "fields": {"exception_function": f"{got[1] & 0x7F:02X}", "code": f"{got[2]:02X}"},
            },
        }
    except mm.InvalidResponseError as exc:
        return {"ok": True, "accepted": False, "reason": f"minimalmodbus: {exc}"}
    except Exception as exc:  # noqa: BLE001 - a raise that is not minimalmodbus's ModbusException
        return {
            "ok": True,
            "accepted": False,
            "raised": True,
            "reason": f"_extract_payload raised {type(exc).__name__}: {exc}",
        }
    REG = mm._Payloadformat.REGISTERS
    try:
        if function == 0x03:
            count = max(1, (payload[0] if payload else 0) // 2)
            values = mm._parse_payload(payload, 3, 0, None, 0, count, 0, False, 0, REG)
            fields = {"byte_count": payload[0], "values": [f"{v:04X}" for v in values]}
            kind = "read-response"
        elif function == 0x06:
            # write_register(registeraddress, value) checks the echo of both.
            reg = word(payload[0:2]) if len(payload) >= 2 else 0
            value = word(payload[2:4]) if len(payload) >= 4 else 0
            mm._parse_payload(payload, 6, reg, value, 0, 1, 0, False, 0, mm._Payloadformat.REGISTER)
            fields = {"register": f"{reg:04X}", "value": f"{value:04X}"}
            kind = "write-single"
        else:
            start = word(payload[0:2]) if len(payload) >= 2 else 0
            count = word(payload[2:4]) if len(payload) >= 4 else 0
            if not 1 <= count <= mm._MAX_NUMBER_OF_REGISTERS_TO_WRITE:
                # write_registers writes 1..123 registers: no request this answers.
                return {"ok": True, "accepted": False,
                        "reason": f"a 10H response for {count} registers answers no request minimalmodbus can send (write_registers: 1..123)"}
            mm._parse_payload(payload, 16, start, [0] * count, 0, count, 0, False, 0, REG)
            fields = {"start": f"{start:04X}", "count": count}
            kind = "write-multiple-response"
    except mm.InvalidResponseError as exc:
        return {"ok": True, "accepted": False, "reason": f"minimalmodbus: {exc}"}
    except Exception as exc:  # noqa: BLE001
        return {
            "ok": True,
            "accepted": False,
            "raised": True,
            "reason": f"_parse_payload raised {type(exc).__name__}: {exc}",
        }
    return {
        "ok": True,
        "accepted": True,
        "message": {"address": f"{address:02X}", "function": f"{function:02X}", "kind": kind, "fields": fields},
    }


def op_encode(req):
    mode = master_side(req, "request", "encodes", "a response")
    msg = req.get("message")
    if not isinstance(msg, dict) or not isinstance(msg.get("fields"), dict):
        raise BadRequest("message must be an object with fields")
    f = msg["fields"]
    address = hexnum(msg, "address")
    function = hexnum(msg, "function")
    kind = msg.get("kind")
    REG = mm._Payloadformat
    if kind == "read-request" and function == 0x03:
        count = num(f, "count")
        # Instrument.read_registers refuses counts outside 1..125 before framing.
        mm._check_int(count, minvalue=1, maxvalue=125, description="number of registers")
        payload = mm._create_payload(3, hexnum(f, "start"), None, 0, count, 0, False, 0, REG.REGISTERS)
    elif kind == "write-single" and function == 0x06:
        payload = mm._create_payload(6, hexnum(f, "register"), hexnum(f, "value"), 0, 1, 0, False, 0, REG.REGISTER)
    elif kind == "write-multiple-request" and function == 0x10:
        values = [int(v, 16) for v in f.get("values", [])]
        if num(f, "count") != len(values) or num(f, "byte_count") != 2 * len(values):
            raise Unsupported("minimalmodbus derives count and byte count from the values")
        if not values:
            raise Unsupported("minimalmodbus cannot write 0 registers")
        payload = mm._create_payload(16, hexnum(f, "start"), values, 0, len(values), 0, False, 0, REG.REGISTERS)
    else:
        raise Unsupported(f"minimalmodbus sends no request of kind {kind} with function {function:02X}H")
    frame = mm._embed_payload(address, mode, function, payload)
    return {"ok": True, "frame": hexs(frame)}


def op_crc(req):
    wire = mm._calculate_crc(parse_hex(req.get("data")))  # low byte first
    return {"ok": True, "crc": f"{wire[1]:02X}{wire[0]:02X}"}


def op_lrc(req):
    return {"ok": True, "lrc": f"{mm._calculate_lrc(parse_hex(req.get('data')))[0]:02X}"}


OPS = {"hello": op_hello, "decode": op_decode, "encode": op_encode, "crc": op_crc, "lrc": op_lrc}


def main() -> int:
    return serve(OPS, log, _OUT, raised="minimalmodbus raised ")


if __name__ == "__main__":
    try:
        sys.exit(main())
    except KeyboardInterrupt:
        sys.exit(0)
