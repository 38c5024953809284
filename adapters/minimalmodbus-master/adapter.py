#!/usr/bin/env python3
"""Master adapter for minimalmodbus's Instrument (the master adapter protocol, role
"master", of ../PROTOCOL.md).

One JSON request per line on stdin, one JSON answer per line on stdout (flushed per line);
logs on stderr. The adapter calls minimalmodbus's public API only and reports what it
returned or raised:

* open: ``serial.Serial(path, baudrate, bytesize, parity, stopbits, timeout=timeout_ms/1000)``
  (pty), or ``serial.serial_for_url("socket://host:port", ...)`` (tcp-rtu), handed to
  ``minimalmodbus.Instrument(port_object, 1, mode=MODE_RTU|MODE_ASCII)``: the instrument's
  documented way to use a port object it did not open. minimalmodbus has no retries: an
  ``open`` answers ``retries: 0`` whatever was asked.
* read: ``read_registers(start, count, functioncode=3)``
* write-single: ``write_register(register, value, functioncode=6)``
* write-multiple: ``write_registers(start, values)`` (10H)
* broadcast: the same writes with ``instrument.address = 0`` (minimalmodbus 2.0 sends,
  reads nothing and sleeps 200 ms).
* loop-back: not offered (minimalmodbus has no 08H call in its API): unsupported.

Set MINIMALMODBUS_MASTER_DEBUG=1 for minimalmodbus's own debug prints (on stderr).

The protocol's loop (reading requests, dispatching them, writing answers), the hello and
the shapes of the answers are ../master_common.py's, shared by the Python master
adapters; this file keeps what is minimalmodbus's own.
"""

from __future__ import annotations

import os
import re
import sys

if sys.path and os.path.abspath(sys.path[0] or ".") == os.path.dirname(os.path.abspath(__file__)):
    del sys.path[0]

import minimalmodbus  # noqa: E402
import serial  # noqa: E402

# The loop, hello and answers the Python master adapters share (adapters/master_common.py);
# appended, so that this folder's neighbours never shadow an installed package.
sys.path.append(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from master_common import (  # noqa: E402
    Unsupported, closing, done, error, exception, hello_answer, ops_of, protocol_stream, raised,
    refuse_hello, serve, values,
)

ADAPTER = "minimalmodbus-master"
OUT = protocol_stream()  # minimalmodbus's debug prints go to stderr

instrument = None

# The messages of minimalmodbus's _check_response_slaveerrorcode, back to the code.
CODE_OF_MESSAGE = {
    "Slave reported illegal function": 0x01,
    "Slave reported illegal data address": 0x02,
    "Slave reported illegal data value": 0x03,
    "Slave reported device failure": 0x04,
    "Slave reported device busy": 0x06,
    "Slave reported negative acknowledge": 0x07,
    "Slave reported memory parity error": 0x08,
    "Slave reported gateway path unavailable": 0x0A,
    "Slave reported gateway target device failed to respond": 0x0B,
}


def close_instrument() -> None:
    global instrument
    if instrument is not None:
        instrument.serial.close()
        instrument = None


def op_open(req: dict) -> dict:
    global instrument
    close_instrument()
    line = req.get("line") or {}
    mode = {"rtu": minimalmodbus.MODE_RTU, "ascii": minimalmodbus.MODE_ASCII}.get(req.get("mode", "rtu"))
    if mode is None:
        raise Unsupported(f"mode {req.get('mode')}")
    settings = dict(
        baudrate=int(req.get("baud", 19200)),
        bytesize=int(req.get("data_bits", 8)),
        parity=str(req.get("parity", "N"))[:1].upper(),
        stopbits=int(req.get("stop_bits", 1)),
        timeout=float(req.get("timeout_ms", 50)) / 1000.0,
        write_timeout=2.0,
    )
    if line.get("kind") == "pty":
        port = serial.Serial(line["path"], **settings)
    elif line.get("kind") == "tcp-rtu":
        port = serial.serial_for_url(f"socket://{line['host']}:{int(line['port'])}", **settings)
    else:
        raise Unsupported(f"line {line.get('kind')}")
    instrument = minimalmodbus.Instrument(port, 1, mode=mode,
                                          debug=bool(os.environ.get("MINIMALMODBUS_MASTER_DEBUG")))
    # minimalmodbus has no retries: it runs with 0, whatever was asked (the gate judges
    # with the settings this answer reports).
    return {"ok": True, "timeout_ms": int(settings["timeout"] * 1000), "retries": 0}


def outcome(call, on_ok) -> dict:
    try:
        value = call()
    except minimalmodbus.SlaveReportedException as exc:
        text = str(exc)
        code = CODE_OF_MESSAGE.get(text)
        m = re.fullmatch(r"Slave reported error code (\d+)", text)
        if m:
            code = int(m.group(1))
        if code is None:
            return error("other", text)
        return exception(code, message=text, note=type(exc).__name__)
    except minimalmodbus.NoResponseError as exc:
        return error("timeout", str(exc))
    except minimalmodbus.InvalidResponseError as exc:
        text = str(exc)
        return error("checksum" if text.startswith("Checksum error") else "invalid-frame", text)
    except minimalmodbus.ModbusException as exc:  # LocalEchoError, MasterReportedException
        return error("other", f"{type(exc).__name__}: {exc}")
    except serial.SerialException as exc:
        return error("other", f"SerialException: {exc}")
    except Exception as exc:  # noqa: BLE001 - undocumented for these calls: the call crashed
        return raised(type(exc).__name__, str(exc))
    return on_ok(value)


def need(unit: int):
    if instrument is None:
        raise RuntimeError("not open")
    instrument.address = unit
    return instrument


def op_read(req: dict) -> dict:
    ins = need(int(req["unit"]))
    start, count = int(req["start"], 16), int(req["count"])
    return outcome(lambda: ins.read_registers(start, count, functioncode=3), values)


def op_write_single(req: dict) -> dict:
    ins = need(int(req["unit"]))
    reg, value = int(req["register"], 16), int(req["value"], 16)
    # write_register checks the echo itself (InvalidResponseError on a mismatch) and
    # returns None: there is no echo to report.
    return outcome(lambda: ins.write_register(reg, value, 0, functioncode=6),
                   lambda _v: done())


def op_write_multiple(req: dict) -> dict:
    ins = need(int(req["unit"]))
    start, registers = int(req["start"], 16), [int(v, 16) for v in req["values"]]
    return outcome(lambda: ins.write_registers(start, registers),
                   lambda _v: done())


def op_loop_back(_req: dict) -> dict:
    raise Unsupported("minimalmodbus's API has no 08H (diagnostics) call")


op_close = closing(close_instrument)


def op_hello(req: dict) -> dict:
    return refuse_hello(req) or hello_answer(
        ADAPTER, "minimalmodbus", minimalmodbus.__version__,
        supports=["read", "write-single", "write-multiple", "broadcast"],
        lines=["pty", "tcp-rtu"], modes=["rtu", "ascii"])


if __name__ == "__main__":
    sys.exit(serve(ops_of(globals()), ADAPTER, OUT))
