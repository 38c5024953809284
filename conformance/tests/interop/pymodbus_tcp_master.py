#!/usr/bin/env python3
"""Interoperability check: pymodbus's Modbus TCP client against `conformance simulate
--tcp HOST:PORT --framing mbap` (a simulated F510 behind a simulated Modbus TCP gateway).

Usage:
    pymodbus_tcp_master.py HOST PORT UNIT [--absent N] [--timeout S]

Prints one JSON object per operation on stdout:
    {"op": "...", "ok": true|false, "detail": "..."}
Exit status: 0 when every operation returned what is expected, 1 otherwise (the failures
are repeated on stderr), 2 when pymodbus is missing.

What it expects of the F510 (manual values): 252FH reads 0510H; a write of the frequency
command 2502H (06H and 10H) reads back; 0039H is not in the map (exception 02H); 08H 0000H
echoes its data; a unit id with no drive behind the gateway is answered with exception
0BH (gateway target device failed to respond) by the gateway.
"""

import argparse
import json
import sys

try:
    from pymodbus.client import ModbusTcpClient
except ImportError as e:
    print(f"pymodbus_tcp_master.py: cannot import pymodbus ({e})", file=sys.stderr)
    sys.exit(2)

failures = []


def report(op, ok, detail):
    print(json.dumps({"op": op, "ok": bool(ok), "detail": detail}), flush=True)
    if not ok:
        failures.append(f"{op}: {detail}")


def describe(r):
    if r.isError():
        return f"exception {getattr(r, 'exception_code', '?'):02X}H"
    return f"registers {[hex(v) for v in getattr(r, 'registers', [])]}"


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("host")
    p.add_argument("port", type=int)
    p.add_argument("unit", type=int)
    p.add_argument("--absent", type=int, default=7)
    p.add_argument("--timeout", type=float, default=2.0)
    a = p.parse_args()
    c = ModbusTcpClient(a.host, port=a.port, timeout=a.timeout, retries=0)
    if not c.connect():
        print(f"cannot connect to {a.host}:{a.port}", file=sys.stderr)
        return 1
    u = a.unit

    r = c.read_holding_registers(0x252F, count=1, device_id=u)
    report("read identification 252FH", not r.isError() and r.registers == [0x0510], describe(r))

    r = c.write_register(0x2502, 1234, device_id=u)
    ok = not r.isError() and r.address == 0x2502 and r.registers == [1234]
    report("06H write 2502H = 1234", ok, describe(r))
    r = c.read_holding_registers(0x2502, count=1, device_id=u)
    report("read back 2502H", not r.isError() and r.registers == [1234], describe(r))

    r = c.write_registers(0x2502, [600], device_id=u)
    report("10H write 2502H = 600", not r.isError(), describe(r))
    r = c.read_holding_registers(0x2502, count=1, device_id=u)
    report("read back 2502H after 10H", not r.isError() and r.registers == [600], describe(r))

    r = c.read_holding_registers(0x0039, count=1, device_id=u)
    report(
        "read 0039H (not in the map): exception 02H",
        r.isError() and r.exception_code == 0x02,
        describe(r),
    )

    r = c.diag_query_data(b"\x12\x34", device_id=u)
    detail = "exception" if r.isError() else f"message {getattr(r, 'message', None)!r}"
    report("08H 0000H loop-back of 1234H", not r.isError() and r.message == b"\x12\x34", detail)

    r = c.read_holding_registers(0x252F, count=1, device_id=a.absent)
    report(
        f"read from unit {a.absent} (no drive): gateway exception 0BH",
        r.isError() and r.exception_code == 0x0B,
        describe(r),
    )
    c.close()
    for f in failures:
        print(f"FAILED: {f}", file=sys.stderr)
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
