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
"""

from __future__ import annotations

import json
import os
import re
import sys

if sys.path and os.path.abspath(sys.path[0] or ".") == os.path.dirname(os.path.abspath(__file__)):
    del sys.path[0]

import minimalmodbus  # noqa: E402
import serial  # noqa: E402

ADAPTER = "minimalmodbus-master"
OUT = sys.stdout
sys.stdout = sys.stderr  # minimalmodbus's debug prints go to stderr, never into the protocol


class Unsupported(Exception):
    pass


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


def h4(v: int) -> str:
    return f"{v & 0xFFFF:04X}"


def op_open(req: dict) -> dict:
    global instrument
    if instrument is not None:
        instrument.serial.close()
        instrument = None
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
            return {"ok": True, "result": "error", "kind": "other", "message": text}
        return {"ok": True, "result": "exception", "code": f"{code:02X}", "message": text,
                "note": type(exc).__name__}
    except minimalmodbus.NoResponseError as exc:
        return {"ok": True, "result": "error", "kind": "timeout", "message": str(exc)}
    except minimalmodbus.InvalidResponseError as exc:
        text = str(exc)
        kind = "checksum" if text.startswith("Checksum error") else "invalid-frame"
        return {"ok": True, "result": "error", "kind": kind, "message": text}
    except minimalmodbus.ModbusException as exc:  # LocalEchoError, MasterReportedException
        return {"ok": True, "result": "error", "kind": "other", "message": f"{type(exc).__name__}: {exc}"}
    except serial.SerialException as exc:
        return {"ok": True, "result": "error", "kind": "other", "message": f"SerialException: {exc}"}
    except Exception as exc:  # noqa: BLE001 - undocumented for these calls: the call crashed
        return {"ok": True, "result": "raised", "type": type(exc).__name__, "message": str(exc)}
    return on_ok(value)


def need(unit: int):
    if instrument is None:
        raise RuntimeError("not open")
    instrument.address = unit
    return instrument


def op_read(req: dict) -> dict:
    ins = need(int(req["unit"]))
    start, count = int(req["start"], 16), int(req["count"])
    return outcome(lambda: ins.read_registers(start, count, functioncode=3),
                   lambda v: {"ok": True, "result": "values", "values": [h4(x) for x in v]})


def op_write_single(req: dict) -> dict:
    ins = need(int(req["unit"]))
    reg, value = int(req["register"], 16), int(req["value"], 16)
    # write_register checks the echo itself (InvalidResponseError on a mismatch) and
    # returns None: there is no echo to report.
    return outcome(lambda: ins.write_register(reg, value, 0, functioncode=6),
                   lambda _v: {"ok": True, "result": "done"})


def op_write_multiple(req: dict) -> dict:
    ins = need(int(req["unit"]))
    start, values = int(req["start"], 16), [int(v, 16) for v in req["values"]]
    return outcome(lambda: ins.write_registers(start, values),
                   lambda _v: {"ok": True, "result": "done"})


def op_loop_back(_req: dict) -> dict:
    raise Unsupported("minimalmodbus's API has no 08H (diagnostics) call")


def op_close(_req: dict) -> dict:
    global instrument
    if instrument is not None:
        instrument.serial.close()
        instrument = None
    return {"ok": True}


def op_hello(req: dict) -> dict:
    if req.get("protocol") != 1 or req.get("role") != "master":
        return {"ok": False, "error": "this adapter speaks protocol 1, role master"}
    return {"ok": True, "protocol": 1, "role": "master", "adapter": ADAPTER,
            "implementation": "minimalmodbus", "version": minimalmodbus.__version__,
            "supports": ["read", "write-single", "write-multiple", "broadcast"],
            "lines": ["pty", "tcp-rtu"], "modes": ["rtu", "ascii"]}


OPS = {"hello": op_hello, "open": op_open, "read": op_read, "write-single": op_write_single,
       "write-multiple": op_write_multiple, "loop-back": op_loop_back, "close": op_close}


def main() -> int:
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
            fn = OPS.get(req.get("op"))
            try:
                answer = fn(req) if fn else {"ok": False, "error": "unsupported",
                                             "detail": f"op {req.get('op')!r}"}
            except Unsupported as exc:
                answer = {"ok": False, "error": "unsupported", "detail": str(exc)}
            except (KeyError, ValueError, TypeError) as exc:
                answer = {"ok": False, "error": f"bad request: {type(exc).__name__}: {exc}"}
            except Exception as exc:  # noqa: BLE001
                print(f"[{ADAPTER}] id={req.get('id')}: {type(exc).__name__}: {exc}", file=sys.stderr)
                answer = {"ok": False, "error": f"{type(exc).__name__}: {exc}"}
            answer = {"id": req.get("id"), **answer}
        try:
            OUT.write(json.dumps(answer, separators=(",", ":")) + "\n")
            OUT.flush()
        except BrokenPipeError:
            return 0
    return 0


if __name__ == "__main__":
    sys.exit(main())
