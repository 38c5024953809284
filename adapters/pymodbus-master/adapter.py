#!/usr/bin/env python3
"""Master adapter for pymodbus's synchronous client (the master adapter protocol,
role "master", of ../PROTOCOL.md).

One JSON request per line on stdin, one JSON answer per line on stdout (flushed per line);
logs on stderr. The adapter calls pymodbus's own client API and reports what it returned:
it never builds or parses a frame.

* open: ``ModbusSerialClient(path, framer=FramerType.RTU|ASCII, baudrate, bytesize, parity,
  stopbits, timeout=timeout_ms/1000, retries=retries)`` on a pty;
  ``ModbusTcpClient(host, port=..., framer=FramerType.RTU, ...)`` for ``tcp-rtu``;
  ``ModbusTcpClient(host, port=..., framer=FramerType.SOCKET, ...)`` for ``mbap``.
* read: ``read_holding_registers(start, count=count, device_id=unit)``
* write-single: ``write_register(register, value, device_id=unit)``
* write-multiple: ``write_registers(start, values, device_id=unit)``
* loop-back: ``diag_query_data(data, device_id=unit)`` (sub-function 0000H only)
* broadcast (unit 0): the same write calls with ``no_response_expected=True``, as pymodbus
  asks a caller to do for a request nobody answers (set PYMODBUS_MASTER_BROADCAST_WAIT=1 to
  call them as for a unicast instead, and see pymodbus wait for a reply to a broadcast).

Set PYMODBUS_MASTER_DEBUG=1 to copy pymodbus's debug log to stderr.

The protocol's loop (reading requests, dispatching them, writing answers), the hello and
the shapes of the answers are ../master_common.py's, shared by the Python master
adapters; this file keeps what is pymodbus's own.
"""

from __future__ import annotations

import logging
import os
import sys

if sys.path and os.path.abspath(sys.path[0] or ".") == os.path.dirname(os.path.abspath(__file__)):
    del sys.path[0]

import pymodbus  # noqa: E402
from pymodbus.logging import Log  # noqa: E402
from pymodbus import FramerType  # noqa: E402
from pymodbus.client import ModbusSerialClient, ModbusTcpClient  # noqa: E402
from pymodbus.exceptions import ConnectionException, ModbusIOException, ModbusException  # noqa: E402

# The loop, hello and answers the Python master adapters share (adapters/master_common.py);
# appended, so that this folder's neighbours never shadow an installed package.
sys.path.append(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from master_common import (  # noqa: E402
    Unsupported, closing, done, echo, error, exception, h4, hello_answer, ops_of, protocol_stream,
    raised, refuse_hello, serve, values,
)

ADAPTER = "pymodbus-master"
OUT = protocol_stream()  # anything pymodbus prints goes to stderr

if os.environ.get("PYMODBUS_MASTER_DEBUG"):
    pymodbus.pymodbus_apply_logging_config(logging.DEBUG)
else:
    logging.getLogger("pymodbus").setLevel(logging.CRITICAL)


client = None
broadcast_wait = bool(os.environ.get("PYMODBUS_MASTER_BROADCAST_WAIT"))


def close_client() -> None:
    global client
    if client is not None:
        client.close()
        client = None


def op_open(req: dict) -> dict:
    global client
    close_client()
    line = req.get("line") or {}
    mode = req.get("mode", "rtu")
    timeout = float(req.get("timeout_ms", 1000)) / 1000.0
    retries = int(req.get("retries", 0))
    kind = line.get("kind")
    framer = {"rtu": FramerType.RTU, "ascii": FramerType.ASCII}.get(mode)
    if framer is None:
        raise Unsupported(f"mode {mode}")
    if kind == "pty":
        client = ModbusSerialClient(
            line["path"],
            framer=framer,
            baudrate=int(req.get("baud", 19200)),
            bytesize=int(req.get("data_bits", 8)),
            parity=str(req.get("parity", "N"))[:1].upper(),
            stopbits=int(req.get("stop_bits", 1)),
            timeout=timeout,
            retries=retries,
        )
    elif kind in ("tcp-rtu", "mbap"):
        if kind == "mbap":
            if mode != "rtu":
                raise Unsupported("mbap carries no ASCII")
            framer = FramerType.SOCKET
        client = ModbusTcpClient(
            line["host"], port=int(line["port"]), framer=framer, timeout=timeout, retries=retries
        )
    else:
        raise Unsupported(f"line {kind}")
    why = connect(client)
    if why is not None:
        where = line.get("path") or f"{line.get('host')}:{line.get('port')}"
        return {"ok": False, "error": f"pymodbus could not open {kind} {where}: {why}"}
    return {"ok": True, "timeout_ms": int(timeout * 1000), "retries": retries}


class _Kept(logging.Handler):
    """Keeps the messages of the records it is handed."""

    def __init__(self) -> None:
        super().__init__(logging.ERROR)
        self.messages: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        self.messages.append(record.getMessage().strip())


def connect(c) -> str | None:
    """Connects the client; None when it did, else why not. pymodbus's connect() returns
    False and only logs what pyserial or the socket raised (such as the EINVAL of a parity
    on a pseudo-terminal), so its log is read for the call."""
    log = logging.getLogger("pymodbus.logging")
    kept = _Kept()
    level = log.level
    log.addHandler(kept)
    log.setLevel(min(level or logging.ERROR, logging.ERROR))
    # pymodbus writes a message that repeats the previous one as "Repeating....": forget it.
    Log.last_log_text = ""
    try:
        ok = c.connect()
    finally:
        log.removeHandler(kept)
        log.setLevel(level)
    if ok:
        return None
    return "; ".join(m.splitlines()[0] for m in kept.messages if m) or "pymodbus gave no reason"


def outcome(call, on_ok) -> dict:
    """Runs one pymodbus call; maps what it returned or raised to an answer."""
    try:
        rr = call()
    except ModbusIOException as exc:
        text = str(exc)
        # sync_execute raises this after its retries are spent ("No response received
        # after N retries"); every CRC/LRC error, short frame or frame of another node is
        # dropped by the framer and ends the same way, so a timeout is all pymodbus tells.
        if "No response received" in text:
            return error("timeout", text)
        return error("other", text)
    except ConnectionException as exc:
        return error("other", str(exc))
    except ModbusException as exc:
        return error("other", f"{type(exc).__name__}: {exc}")
    except Exception as exc:  # noqa: BLE001 - the call crashed: report it as raised
        return raised(type(exc).__name__, str(exc))
    if rr is None:
        return done()
    if rr.isError():
        return exception(rr.exception_code, note=type(rr).__name__)
    answer = on_ok(rr)
    answer.setdefault("note", type(rr).__name__)
    return answer


def need_client():
    if client is None:
        raise RuntimeError("not open")
    return client


def op_read(req: dict) -> dict:
    c = need_client()
    start, count, unit = int(req["start"], 16), int(req["count"]), int(req["unit"])
    return outcome(
        lambda: c.read_holding_registers(start, count=count, device_id=unit),
        lambda rr: values(rr.registers),
    )


def _nre(unit: int) -> bool:
    return unit == 0 and not broadcast_wait


def op_write_single(req: dict) -> dict:
    c = need_client()
    reg, value, unit = int(req["register"], 16), int(req["value"], 16), int(req["unit"])
    return outcome(
        lambda: c.write_register(reg, value, device_id=unit, no_response_expected=_nre(unit)),
        lambda rr: done(echo={"register": h4(rr.address),
                              "value": h4(rr.registers[0]) if rr.registers else None}),
    )


def op_write_multiple(req: dict) -> dict:
    c = need_client()
    start, unit = int(req["start"], 16), int(req["unit"])
    registers = [int(v, 16) for v in req["values"]]
    return outcome(
        lambda: c.write_registers(start, registers, device_id=unit, no_response_expected=_nre(unit)),
        lambda rr: done(echo={"start": h4(rr.address), "count": rr.count}),
    )


def op_loop_back(req: dict) -> dict:
    c = need_client()
    if int(req.get("test_code", "0000"), 16) != 0:
        raise Unsupported("pymodbus's client offers loop-back 08H only as diag_query_data (0000H)")
    data = bytes(int(t, 16) for t in str(req.get("data", "")).split())
    unit = int(req["unit"])

    def on_echo(rr):
        msg = rr.message if isinstance(rr.message, (bytes, bytearray)) else b""
        if isinstance(rr.message, int):
            msg = rr.message.to_bytes(2, "big")
        return echo(getattr(rr, "sub_function_code", 0), msg)

    return outcome(lambda: c.diag_query_data(data, device_id=unit), on_echo)


op_close = closing(close_client)


def op_hello(req: dict) -> dict:
    return refuse_hello(req) or hello_answer(
        ADAPTER, "pymodbus", pymodbus.__version__,
        supports=["read", "write-single", "write-multiple", "loop-back", "broadcast"],
        lines=["pty", "tcp-rtu", "mbap"], modes=["rtu", "ascii"])


if __name__ == "__main__":
    sys.exit(serve(ops_of(globals()), ADAPTER, OUT, at_end=close_client))
