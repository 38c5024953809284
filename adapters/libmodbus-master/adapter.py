#!/usr/bin/env python3
"""Master adapter for libmodbus's client (the master adapter protocol, role "master", of
../PROTOCOL.md), through ctypes: the adapter calls libmodbus.so's public functions and
reports their return value and errno; no frame is built or parsed here.

* open (pty): ``modbus_new_rtu(path, baud, parity, data_bits, stop_bits)``,
  ``modbus_set_response_timeout(ctx, timeout_ms)``, ``modbus_connect``; (mbap):
  ``modbus_new_tcp(host, port)``. libmodbus has no ASCII and no RTU over TCP, and no
  retries of its own: ``open`` answers ``retries: 0`` whatever was asked.
  The byte timeout is libmodbus's default (500 ms) unless LIBMODBUS_MASTER_BYTE_TIMEOUT_MS
  is set; the error recovery mode is libmodbus's default (none) unless
  LIBMODBUS_MASTER_RECOVERY=protocol.
* read: ``modbus_set_slave(ctx, unit)``, ``modbus_read_registers(ctx, start, count, dest)``
* write-single: ``modbus_write_register``; write-multiple: ``modbus_write_registers``
* broadcast: the same writes after ``modbus_set_slave(ctx, 0)`` (libmodbus then does not
  wait for a reply).
* loop-back: not offered (libmodbus has no 08H call; only the raw request API).

A call that returns -1 is mapped from errno (see README.md).

The protocol's loop (reading requests, dispatching them, writing answers), the hello and
the shapes of the answers are ../master_common.py's, shared by the Python master
adapters; this file keeps what is libmodbus's own.
"""

from __future__ import annotations

import ctypes
import ctypes.util
import errno as E
import os
import sys

# The loop, hello and answers the Python master adapters share (adapters/master_common.py);
# appended, so that this folder's neighbours never shadow an installed package.
sys.path.append(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from master_common import (  # noqa: E402
    Unsupported, closing, done, error, exception, hello_answer, ops_of, protocol_stream,
    refuse_hello, serve, values,
)

ADAPTER = "libmodbus-master"
OUT = protocol_stream()

lib = ctypes.CDLL(ctypes.util.find_library("modbus") or "libmodbus.so.5", use_errno=True)
lib.modbus_new_rtu.restype = ctypes.c_void_p
lib.modbus_new_rtu.argtypes = [ctypes.c_char_p, ctypes.c_int, ctypes.c_char, ctypes.c_int, ctypes.c_int]
lib.modbus_new_tcp.restype = ctypes.c_void_p
lib.modbus_new_tcp.argtypes = [ctypes.c_char_p, ctypes.c_int]
for name in ("modbus_connect", "modbus_close", "modbus_free", "modbus_flush"):
    getattr(lib, name).argtypes = [ctypes.c_void_p]
lib.modbus_close.restype = None
lib.modbus_free.restype = None
lib.modbus_set_slave.argtypes = [ctypes.c_void_p, ctypes.c_int]
lib.modbus_set_response_timeout.argtypes = [ctypes.c_void_p, ctypes.c_uint32, ctypes.c_uint32]
lib.modbus_set_byte_timeout.argtypes = [ctypes.c_void_p, ctypes.c_uint32, ctypes.c_uint32]
lib.modbus_set_error_recovery.argtypes = [ctypes.c_void_p, ctypes.c_int]
lib.modbus_set_debug.argtypes = [ctypes.c_void_p, ctypes.c_int]
lib.modbus_read_registers.argtypes = [ctypes.c_void_p, ctypes.c_int, ctypes.c_int, ctypes.POINTER(ctypes.c_uint16)]
lib.modbus_write_register.argtypes = [ctypes.c_void_p, ctypes.c_int, ctypes.c_uint16]
lib.modbus_write_registers.argtypes = [ctypes.c_void_p, ctypes.c_int, ctypes.c_int, ctypes.POINTER(ctypes.c_uint16)]
lib.modbus_strerror.restype = ctypes.c_char_p
lib.modbus_strerror.argtypes = [ctypes.c_int]

MODBUS_ENOBASE = 112345678
EMBXGTAR = MODBUS_ENOBASE + 0x0B
EMBBADCRC, EMBBADDATA, EMBBADEXC, EMBUNKEXC, EMBMDATA, EMBBADSLAVE = (EMBXGTAR + i for i in range(1, 7))
MODBUS_ERROR_RECOVERY_PROTOCOL = 1 << 2


def version() -> str:
    parts = []
    for n in ("libmodbus_version_major", "libmodbus_version_minor", "libmodbus_version_micro"):
        parts.append(str(ctypes.c_uint.in_dll(lib, n).value))
    return ".".join(parts)


ctx = None


def close_ctx() -> None:
    global ctx
    if ctx:
        lib.modbus_close(ctx)
        lib.modbus_free(ctx)
    ctx = None


def op_open(req: dict) -> dict:
    global ctx
    close_ctx()
    line = req.get("line") or {}
    mode = req.get("mode", "rtu")
    if mode != "rtu":
        raise Unsupported("libmodbus has no ASCII mode")
    if line.get("kind") == "pty":
        parity = str(req.get("parity", "N"))[:1].upper().encode()
        c = lib.modbus_new_rtu(line["path"].encode(), int(req.get("baud", 19200)), parity,
                               int(req.get("data_bits", 8)), int(req.get("stop_bits", 1)))
    elif line.get("kind") == "mbap":
        c = lib.modbus_new_tcp(str(line["host"]).encode(), int(line["port"]))
    else:
        raise Unsupported(f"line {line.get('kind')} (libmodbus has no RTU over TCP)")
    if not c:
        return {"ok": False, "error": f"modbus_new_*: {os.strerror(ctypes.get_errno())}"}
    ms = int(req.get("timeout_ms", 500))
    lib.modbus_set_response_timeout(c, ms // 1000, (ms % 1000) * 1000)
    bt = os.environ.get("LIBMODBUS_MASTER_BYTE_TIMEOUT_MS")
    if bt:
        lib.modbus_set_byte_timeout(c, int(bt) // 1000, (int(bt) % 1000) * 1000)
    if os.environ.get("LIBMODBUS_MASTER_RECOVERY") == "protocol":
        lib.modbus_set_error_recovery(c, MODBUS_ERROR_RECOVERY_PROTOCOL)
    if os.environ.get("LIBMODBUS_MASTER_DEBUG"):
        lib.modbus_set_debug(c, 1)
    if lib.modbus_connect(c) == -1:
        err = ctypes.get_errno()
        lib.modbus_free(c)
        return {"ok": False, "error": f"modbus_connect: {lib.modbus_strerror(err).decode()}"}
    ctx = c
    # libmodbus has no retries: it runs with 0, whatever was asked.
    return {"ok": True, "timeout_ms": ms, "retries": 0}


def failure() -> dict:
    err = ctypes.get_errno()
    text = lib.modbus_strerror(err).decode(errors="replace")
    if MODBUS_ENOBASE < err <= EMBXGTAR:
        return exception(err - MODBUS_ENOBASE, message=text)
    if err in (E.ETIMEDOUT,):
        kind = "timeout"
    elif err == EMBBADCRC:
        kind = "checksum"
    elif err in (EMBBADDATA, EMBBADEXC, EMBUNKEXC, EMBMDATA, EMBBADSLAVE):
        kind = "invalid-frame"
    else:
        kind = "other"
    return error(kind, text, errno=err)


def need(unit: int):
    if not ctx:
        raise RuntimeError("not open")
    if lib.modbus_set_slave(ctx, unit) == -1:
        raise ValueError(f"modbus_set_slave({unit}) refused")
    return ctx


def op_read(req: dict) -> dict:
    c = need(int(req["unit"]))
    start, count = int(req["start"], 16), int(req["count"])
    dest = (ctypes.c_uint16 * max(count, 1))()
    ctypes.set_errno(0)
    rc = lib.modbus_read_registers(c, start, count, dest)
    if rc == -1:
        return failure()
    return values(dest[i] for i in range(rc))


def op_write_single(req: dict) -> dict:
    c = need(int(req["unit"]))
    ctypes.set_errno(0)
    rc = lib.modbus_write_register(c, int(req["register"], 16), int(req["value"], 16))
    if rc == -1:
        return failure()
    return done()


def op_write_multiple(req: dict) -> dict:
    c = need(int(req["unit"]))
    registers = [int(v, 16) for v in req["values"]]
    src = (ctypes.c_uint16 * len(registers))(*registers)
    ctypes.set_errno(0)
    rc = lib.modbus_write_registers(c, int(req["start"], 16), len(registers), src)
    if rc == -1:
        return failure()
    return done(echo={"count": rc})


def op_loop_back(_req: dict) -> dict:
    raise Unsupported("libmodbus has no 08H call (only modbus_send_raw_request)")


op_close = closing(close_ctx)


def op_hello(req: dict) -> dict:
    return refuse_hello(req) or hello_answer(
        ADAPTER, "libmodbus", version(),
        supports=["read", "write-single", "write-multiple", "broadcast"],
        lines=["pty", "mbap"], modes=["rtu"])


if __name__ == "__main__":
    sys.exit(serve(ops_of(globals()), ADAPTER, OUT, at_end=close_ctx))
