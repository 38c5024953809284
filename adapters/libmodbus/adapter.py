#!/usr/bin/env python3
"""Conformance-gate adapter for libmodbus (protocol 1, see ../PROTOCOL.md).

libmodbus (C) has no public frame decoder or encoder: it frames inside its
send and receive calls. So the adapter drives those calls, through ctypes on
the system's libmodbus.so, over a fresh pseudo-terminal per case (libmodbus
opens the pty's slave side as its serial port; the adapter holds the master
side and plays the other station):

* decode, request: the frame is written to the line, then libmodbus's server
  side ``modbus_receive`` reads it. A frame it returns is accepted (the bytes
  it returns are the message its application gets); -1 or 0 (a frame for
  another node) is a rejection, with ``modbus_strerror``. Then
  ``modbus_reply`` from a mapping of all 65536 registers answers it, and the
  reply is given as a ``note``.
* decode, response: the adapter plays the device: libmodbus's client sends
  the request this frame answers (``modbus_read_registers``,
  ``modbus_write_register``, ``modbus_write_registers``); the adapter reads
  that request off the line and answers it with the frame under test. A call
  that returns data is accepted with what it returned; -1 with errno
  ``MODBUS_ENOBASE + code`` is an accepted exception response; any other -1
  is a rejection.
* encode, request: the message is sent with those same client calls and the
  bytes libmodbus wrote are read off the line.
* encode, response: the adapter sends the request the message answers and
  reads what ``modbus_reply`` (from a mapping holding the message's values)
  or ``modbus_reply_exception`` writes.

libmodbus has no ASCII mode, no 08H, and keeps its CRC function private:
those operations are "unsupported". The README lists every other case the
adapter cannot express (and so skips).
"""

from __future__ import annotations

import ctypes
import ctypes.util
import errno as errno_mod
import json
import os
import select
import sys
import termios
import threading
import time
import tty

_OUT = sys.stdout
sys.stdout = sys.stderr

# The helpers and the protocol loop the Python adapters share (adapters/adapter_common.py);
# appended, so that this folder's neighbours never shadow an installed package.
sys.path.append(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from adapter_common import (  # noqa: E402,F401
    BadRequest,
    Unsupported,
    crc16,
    hello,
    hexnum,
    hexs,
    num,
    parse_hex,
    serve,
)

MODBUS_ENOBASE = 112345678
EXCEPTION_MAX = 12  # MODBUS_EXCEPTION_MAX in modbus.h (codes 01..0BH; 09H unused)
MAX_ADU = 256
# Timeouts of libmodbus on the pty. The line is a pty, so bytes arrive at once:
# these only bound how long a frame that libmodbus finds incomplete takes. The
# response timeout is long where the adapter's device thread answers (a loaded
# machine must not turn a late thread into a rejection) and short where nobody does.
RESPONSE_TIMEOUT_US = 900_000
NO_ANSWER_TIMEOUT_US = 10_000
BYTE_TIMEOUT_US = 20_000
INDICATION_TIMEOUT_US = 60_000


def log(msg: str) -> None:
    sys.stderr.write(f"[libmodbus-adapter] {msg}\n")
    sys.stderr.flush()


class Mapping(ctypes.Structure):
    _fields_ = [
        ("nb_bits", ctypes.c_int),
        ("start_bits", ctypes.c_int),
        ("nb_input_bits", ctypes.c_int),
        ("start_input_bits", ctypes.c_int),
        ("nb_input_registers", ctypes.c_int),
        ("start_input_registers", ctypes.c_int),
        ("nb_registers", ctypes.c_int),
        ("start_registers", ctypes.c_int),
        ("tab_bits", ctypes.POINTER(ctypes.c_uint8)),
        ("tab_input_bits", ctypes.POINTER(ctypes.c_uint8)),
        ("tab_input_registers", ctypes.POINTER(ctypes.c_uint16)),
        ("tab_registers", ctypes.POINTER(ctypes.c_uint16)),
    ]


def load_libmodbus():
    name = ctypes.util.find_library("modbus") or "libmodbus.so.5"
    lib = ctypes.CDLL(name, use_errno=True)
    P, I, U32 = ctypes.c_void_p, ctypes.c_int, ctypes.c_uint32
    U8P = ctypes.POINTER(ctypes.c_uint8)
    U16P = ctypes.POINTER(ctypes.c_uint16)
    sig = {
        "modbus_new_rtu": (P, [ctypes.c_char_p, I, ctypes.c_char, I, I]),
        "modbus_set_slave": (I, [P, I]),
        "modbus_connect": (I, [P]),
        "modbus_close": (None, [P]),
        "modbus_free": (None, [P]),
        "modbus_set_response_timeout": (I, [P, U32, U32]),
        "modbus_set_byte_timeout": (I, [P, U32, U32]),
        "modbus_set_indication_timeout": (I, [P, U32, U32]),
        "modbus_receive": (I, [P, U8P]),
        "modbus_reply": (I, [P, U8P, I, ctypes.POINTER(Mapping)]),
        "modbus_reply_exception": (I, [P, U8P, ctypes.c_uint]),
        "modbus_read_registers": (I, [P, I, I, U16P]),
        "modbus_write_register": (I, [P, I, ctypes.c_uint16]),
        "modbus_write_registers": (I, [P, I, I, U16P]),
        "modbus_mapping_new_start_address": (
            ctypes.POINTER(Mapping),
            [ctypes.c_uint] * 8,
        ),
        "modbus_mapping_free": (None, [ctypes.POINTER(Mapping)]),
        "modbus_strerror": (ctypes.c_char_p, [I]),
    }
    for fn, (res, args) in sig.items():
        f = getattr(lib, fn)
        f.restype = res
        f.argtypes = args
    return lib


LIB = None
VERSION = "unknown"


def strerror(code: int) -> str:
    text = LIB.modbus_strerror(code)
    return text.decode("utf-8", "replace") if text else f"errno {code}"


def libmodbus_version() -> str:
    # libmodbus_version_major/minor/micro are exported unsigned ints.
    try:
        parts = [ctypes.c_uint.in_dll(LIB, f"libmodbus_version_{p}").value for p in ("major", "minor", "micro")]
        return ".".join(str(p) for p in parts)
    except ValueError:
        return "unknown"


# --------------------------------------------------------------------------
# The line: a fresh pty per case, libmodbus on its slave side.
# --------------------------------------------------------------------------


class Line:
    """A pty whose slave side libmodbus opens as its serial port."""

    def __init__(self, slave_address: int, response_timeout_us: int = RESPONSE_TIMEOUT_US):
        self.master, slave = os.openpty()
        tty.setraw(slave)
        attrs = termios.tcgetattr(slave)
        attrs[3] &= ~termios.ECHO
        termios.tcsetattr(slave, termios.TCSANOW, attrs)
        self.path = os.ttyname(slave)
        # Keep the slave open until libmodbus has it, so the pty does not hang up.
        self._slave = slave
        self.ctx = LIB.modbus_new_rtu(self.path.encode(), 9600, b"N", 8, 1)
        if not self.ctx:
            self.close()
            raise OSError(f"modbus_new_rtu failed: {strerror(ctypes.get_errno())}")
        if LIB.modbus_connect(self.ctx) != 0:
            e = ctypes.get_errno()
            self.close()
            raise OSError(f"modbus_connect {self.path} failed: {strerror(e)}")
        if LIB.modbus_set_slave(self.ctx, slave_address) != 0:
            self.close()
            raise Unsupported(f"modbus_set_slave refuses address {slave_address:02X}H")
        LIB.modbus_set_response_timeout(self.ctx, 0, response_timeout_us)
        LIB.modbus_set_byte_timeout(self.ctx, 0, BYTE_TIMEOUT_US)
        LIB.modbus_set_indication_timeout(self.ctx, 0, INDICATION_TIMEOUT_US)

    def write(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            n = os.write(self.master, view)
            view = view[n:]

    def read(self, want: int | None = None, timeout: float = 0.0) -> bytes:
        """Reads what is on the line: `want` bytes (waiting up to `timeout`), or all there is."""
        out = bytearray()
        deadline = time.monotonic() + timeout
        while want is None or len(out) < want:
            left = max(0.0, deadline - time.monotonic())
            r, _, _ = select.select([self.master], [], [], left)
            if not r:
                break
            try:
                chunk = os.read(self.master, 512)
            except OSError:
                break
            if not chunk:
                break
            out += chunk
        return bytes(out)

    def close(self) -> None:
        if getattr(self, "ctx", None):
            LIB.modbus_close(self.ctx)
            LIB.modbus_free(self.ctx)
            self.ctx = None
        for fd in (getattr(self, "_slave", None), getattr(self, "master", None)):
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:
                    pass
        self._slave = self.master = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def with_crc(body: bytes) -> bytes:
    """A request the adapter itself sends to libmodbus's server (its CRC is not judged)."""
    return body + crc16(body)


def server_address(address: int) -> int:
    """The address the libmodbus server gets: the frame's, or any for a broadcast."""
    if address == 0:
        return 1
    if address > 247:
        raise Unsupported(
            f"a libmodbus server cannot have address {address:02X}H (modbus_set_slave takes 0..247)"
        )
    return address


def client_address(address: int) -> int:
    if address == 0:
        raise Unsupported("libmodbus's client waits for no response to a broadcast (address 00H)")
    if address > 247:
        raise Unsupported(f"modbus_set_slave refuses address {address:02X}H")
    return address


# --------------------------------------------------------------------------
# Messages of the bytes libmodbus returned
# --------------------------------------------------------------------------


def request_message(adu: bytes) -> dict:
    """The message of a request frame libmodbus's modbus_receive returned (CRC included)."""
    a, fc, pdu = adu[0], adu[1], adu[2:-2]
    head = {"address": f"{a:02X}", "function": f"{fc:02X}"}
    w = lambda i: (pdu[i] << 8) | pdu[i + 1]  # noqa: E731
    if fc == 0x03 and len(pdu) == 4:
        return {**head, "kind": "read-request", "fields": {"start": f"{w(0):04X}", "count": w(2)}}
    if fc == 0x06 and len(pdu) == 4:
        return {**head, "kind": "write-single", "fields": {"register": f"{w(0):04X}", "value": f"{w(2):04X}"}}
    if fc == 0x10 and len(pdu) >= 5:
        data = pdu[5:]
        values = [f"{(data[i] << 8) | data[i + 1]:04X}" for i in range(0, len(data) - 1, 2)]
        return {
            **head,
            "kind": "write-multiple-request",
            "fields": {"start": f"{w(0):04X}", "count": w(2), "byte_count": pdu[4], "values": values},
        }
    return {**head, "kind": "other", "fields": {"data": hexs(pdu)}}


# --------------------------------------------------------------------------
# Operations
# --------------------------------------------------------------------------


def full_mapping():
    m = LIB.modbus_mapping_new_start_address(0, 0, 0, 0, 0, 0x10000, 0, 0)
    if not m:
        raise OSError("modbus_mapping_new_start_address failed")
    return m


def decode_request(frame: bytes) -> dict:
    address = frame[0] if frame else 1
    with Line(server_address(address), NO_ANSWER_TIMEOUT_US) as line:
        line.write(frame)
        buf = (ctypes.c_uint8 * MAX_ADU)()
        rc = LIB.modbus_receive(line.ctx, buf)
        err = ctypes.get_errno()
        if rc == 0:
            return {"accepted": False, "reason": "modbus_receive returned 0: libmodbus ignored the frame (not for this server)"}
        if rc < 0:
            left = line.read(None, 0.0)
            tail = f"; {len(left)} bytes left unread" if left else ""
            return {"accepted": False, "reason": f"modbus_receive: {strerror(err)}{tail}"}
        got = bytes(buf[:rc])
        answer = {"accepted": True, "message": request_message(got)}
        notes = []
        if len(got) != len(frame):
            notes.append(f"modbus_receive returned {len(got)} of the {len(frame)} bytes ({hexs(got)})")
        mapping = full_mapping()
        try:
            line.read(None, 0.0)  # drop bytes it left unread
            LIB.modbus_reply(line.ctx, buf, rc, mapping)
            reply = line.read(None, 0.005)
        finally:
            LIB.modbus_mapping_free(mapping)
        notes.append(f"modbus_reply answers {hexs(reply)}" if reply else "modbus_reply sends nothing")
        answer["note"] = "; ".join(notes)
        return answer


def play_device(line: Line, request_len: int, frame: bytes, seen: list) -> None:
    """The device: reads libmodbus's request off the line, answers with the frame under test."""
    req = line.read(request_len, 1.0)
    seen.append(req)
    if len(req) == request_len:
        line.write(frame)


def call_client(frame: bytes, address: int, fc: int, plan) -> tuple[int, int, object]:
    """Runs one client call against a device that answers with `frame`."""
    with Line(client_address(address)) as line:
        request_len, call, result = plan(line.ctx)
        seen: list = []
        device = threading.Thread(target=play_device, args=(line, request_len, frame, seen), daemon=True)
        device.start()
        ctypes.set_errno(0)
        rc = call()
        err = ctypes.get_errno()
        device.join(2.0)
        if not seen or len(seen[0]) != request_len:
            raise OSError(f"libmodbus did not send the expected {request_len}-byte request (got {seen})")
        return rc, err, result


def decode_response(frame: bytes) -> dict:
    address = frame[0] if frame else 1
    fc = frame[1] & 0x7F if len(frame) >= 2 else 0x03
    exception = len(frame) >= 2 and frame[1] & 0x80
    if fc == 0x08:
        raise Unsupported("libmodbus 3.1.6 has no 08H: its client sends no loop-back request")
    if fc == 0x03:
        count = 1 if exception else max(1, (frame[2] if len(frame) > 2 else 2) // 2)
        if count > 125:
            return {"accepted": False, "reason": f"a read response of {count} registers answers no request libmodbus sends (1..125)"}

        def plan(ctx):
            dest = (ctypes.c_uint16 * 125)()
            return 8, lambda: LIB.modbus_read_registers(ctx, 0, count, dest), dest

    elif fc == 0x06:
        reg = (frame[2] << 8 | frame[3]) if len(frame) >= 4 and not exception else 0
        value = (frame[4] << 8 | frame[5]) if len(frame) >= 6 and not exception else 0

        def plan(ctx):
            return 8, lambda: LIB.modbus_write_register(ctx, reg, value), None

    elif fc == 0x10:
        start = (frame[2] << 8 | frame[3]) if len(frame) >= 4 and not exception else 0
        count = (frame[4] << 8 | frame[5]) if len(frame) >= 6 and not exception else 1
        if not 1 <= count <= 123:
            return {"accepted": False, "reason": f"a 10H response for {count} registers answers no request libmodbus sends (1..123)"}

        def plan(ctx):
            src = (ctypes.c_uint16 * count)()
            return 9 + 2 * count, lambda: LIB.modbus_write_registers(ctx, start, count, src), None

    else:
        raise Unsupported(f"libmodbus's client is not asked for function {fc:02X}H by this protocol's kinds")
    rc, err, dest = call_client(frame, address, fc, plan)
    head = {"address": f"{address:02X}"}
    if rc >= 0:
        if fc == 0x03:
            values = [f"{dest[i]:04X}" for i in range(rc)]
            msg = {**head, "function": "03", "kind": "read-response", "fields": {"byte_count": 2 * rc, "values": values}}
        elif fc == 0x06:
            msg = {**head, "function": "06", "kind": "write-single", "fields": {"register": f"{reg:04X}", "value": f"{value:04X}"}}
        else:
            msg = {**head, "function": "10", "kind": "write-multiple-response", "fields": {"start": f"{start:04X}", "count": rc}}
        return {"accepted": True, "message": msg}
    if MODBUS_ENOBASE < err < MODBUS_ENOBASE + EXCEPTION_MAX:
        code = err - MODBUS_ENOBASE
        return {
            "accepted": True,
            "note": f"libmodbus returned -1 with errno {strerror(err)!r}",
            "message": {**head, "function": f"{fc | 0x80:02X}", "kind": "exception",
                        "fields": {"exception_function": f"{fc:02X}", "code": f"{code:02X}"}},
        }
    return {"accepted": False, "reason": f"libmodbus's client: {strerror(err) if err else 'failed'}"}


def encode_request(msg: dict) -> bytes:
    address, fc, kind, f = hexnum(msg, "address"), hexnum(msg, "function"), msg.get("kind"), msg["fields"]
    if address > 247:
        raise Unsupported(f"modbus_set_slave refuses address {address:02X}H")
    if kind == "read-request" and fc == 0x03:
        start, count = hexnum(f, "start"), num(f, "count")
        if not 1 <= count <= 125:
            raise Unsupported(f"modbus_read_registers refuses {count} registers (1..125)")
        dest = (ctypes.c_uint16 * 125)()
        call = lambda ctx: LIB.modbus_read_registers(ctx, start, count, dest)  # noqa: E731
    elif kind == "write-single" and fc == 0x06:
        reg, value = hexnum(f, "register"), hexnum(f, "value")
        call = lambda ctx: LIB.modbus_write_register(ctx, reg, value)  # noqa: E731
    elif kind == "write-multiple-request" and fc == 0x10:
        values = [int(v, 16) for v in f.get("values", [])]
        if num(f, "count") != len(values) or num(f, "byte_count") != 2 * len(values):
            raise Unsupported("modbus_write_registers derives count and byte count from the values")
        if not 1 <= len(values) <= 123:
            raise Unsupported(f"modbus_write_registers refuses {len(values)} registers (1..123)")
        src = (ctypes.c_uint16 * len(values))(*values)
        start = hexnum(f, "start")
        call = lambda ctx: LIB.modbus_write_registers(ctx, start, len(values), src)  # noqa: E731
    else:
        raise Unsupported(f"libmodbus's client sends no {kind} with function {fc:02X}H")
    with Line(address, NO_ANSWER_TIMEOUT_US) as line:
        call(line.ctx)  # no device answers: the call times out; its request is on the line
        return line.read(None, 0.0)


def encode_response(msg: dict) -> bytes:
    address, fc, kind, f = hexnum(msg, "address"), hexnum(msg, "function"), msg.get("kind"), msg["fields"]
    if address == 0 or address > 247:
        raise Unsupported(f"a libmodbus server does not answer as address {address:02X}H")
    regs_start, regs = 0, []
    if kind == "read-response" and fc == 0x03:
        values = [int(v, 16) for v in f.get("values", [])]
        if num(f, "byte_count") != 2 * len(values):
            raise Unsupported("modbus_reply derives the byte count from the registers read")
        if not 1 <= len(values) <= 125:
            raise Unsupported(f"no request makes modbus_reply answer {len(values)} registers")
        request = bytes([address, 3, 0, 0, 0, len(values)])
        regs = values
    elif kind == "write-single" and fc == 0x06:
        reg, value = hexnum(f, "register"), hexnum(f, "value")
        request = bytes([address, 6, reg >> 8, reg & 0xFF, value >> 8, value & 0xFF])
        regs_start, regs = reg, [0]
    elif kind == "write-multiple-response" and fc == 0x10:
        start, count = hexnum(f, "start"), num(f, "count")
        if not 1 <= count <= 123 or start + count > 0x10000:
            raise Unsupported(f"no request makes modbus_reply answer a write of {count} registers at {start:04X}H")
        request = bytes([address, 0x10, start >> 8, start & 0xFF, count >> 8, count & 0xFF, 2 * count]) + bytes(2 * count)
        regs_start, regs = start, [0] * count
    elif kind == "exception":
        ef, code = hexnum(f, "exception_function"), hexnum(f, "code")
        if fc != ef | 0x80:
            raise Unsupported("modbus_reply_exception sends the request's function | 80H")
        if not 1 <= code < EXCEPTION_MAX:
            raise Unsupported(f"modbus_reply_exception refuses code {code:02X}H (01..0BH)")
        if ef == 0x03:
            request = bytes([address, 3, 0, 0, 0, 1])
        elif ef == 0x06:
            request = bytes([address, 6, 0, 0, 0, 0])
        elif ef == 0x10:
            request = bytes([address, 0x10, 0, 0, 0, 1, 2, 0, 0])
        else:
            raise Unsupported(f"libmodbus's server receives no {ef:02X}H request to answer")
    else:
        raise Unsupported(f"libmodbus's server sends no {kind} with function {fc:02X}H")
    with Line(address, NO_ANSWER_TIMEOUT_US) as line:
        line.write(with_crc(request))
        buf = (ctypes.c_uint8 * MAX_ADU)()
        rc = LIB.modbus_receive(line.ctx, buf)
        if rc <= 0:
            raise OSError(f"libmodbus's server did not take the adapter's request: {strerror(ctypes.get_errno())}")
        if kind == "exception":
            LIB.modbus_reply_exception(line.ctx, buf, code)
        else:
            mapping = LIB.modbus_mapping_new_start_address(0, 0, 0, 0, regs_start, len(regs), 0, 0)
            try:
                for i, v in enumerate(regs):
                    mapping.contents.tab_registers[i] = v
                LIB.modbus_reply(line.ctx, buf, rc, mapping)
            finally:
                LIB.modbus_mapping_free(mapping)
        return line.read(None, 0.005)


def op_hello(req):
    return hello(req, "libmodbus-adapter", "libmodbus", VERSION, ["decode:rtu", "encode:rtu"])


def op_decode(req):
    if req.get("mode") != "rtu":
        raise Unsupported("libmodbus has no ASCII mode")
    frame = parse_hex(req.get("frame"))
    direction = req.get("direction")
    if direction == "request":
        return {"ok": True, **decode_request(frame)}
    if direction == "response":
        return {"ok": True, **decode_response(frame)}
    raise BadRequest(f"bad direction {direction!r}")


def op_encode(req):
    if req.get("mode") != "rtu":
        raise Unsupported("libmodbus has no ASCII mode")
    msg = req.get("message")
    if not isinstance(msg, dict) or not isinstance(msg.get("fields"), dict):
        raise BadRequest("message must be an object with fields")
    direction = req.get("direction")
    frame = encode_request(msg) if direction == "request" else encode_response(msg)
    return {"ok": True, "frame": hexs(frame)}


OPS = {"hello": op_hello, "decode": op_decode, "encode": op_encode}


def main() -> int:
    global LIB, VERSION
    try:
        LIB = load_libmodbus()
        VERSION = libmodbus_version()
    except (OSError, AttributeError) as exc:
        log(f"cannot load libmodbus (Debian: apt-get install libmodbus-dev): {exc}")
        return 1
    return serve(OPS, log, _OUT)


if __name__ == "__main__":
    try:
        sys.exit(main())
    except KeyboardInterrupt:
        sys.exit(0)
