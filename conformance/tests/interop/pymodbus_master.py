#!/usr/bin/env python3
"""Interoperability check: pymodbus as the Modbus master against `conformance simulate`.

Usage:
    pymodbus_master.py PORT MODE [MODEL] [--address N] [--baud N] [--parity auto|E|O|N]
                       [--timeout S] [-v]

PORT is the serial device (the simulator's pty slave or its --link path), MODE is rtu or
ascii, MODEL is the simulated drive model (f510 by default; l510, a510, e510 also known).

Prints one JSON object per operation on stdout:
    {"op": "...", "ok": true|false, "detail": "..."}
Exit status: 0 when every operation returned what is expected, 1 otherwise (the failures
are repeated on stderr), 2 on a usage error or when pymodbus/pyserial are missing.

Only pymodbus (3.x) and pyserial are needed. Notes on pymodbus on a Linux pty:
  * A pty has no parity and no 7-bit characters: the kernel silently clears PARENB/CS7,
    and glibc's tcsetattr() then fails with EINVAL when none of the requested changes took
    effect. pymodbus reconfigures the port a second time right after opening it (to set
    timeout=0), so 8E1 always fails on a pty ("(22, 'Invalid argument')"). --parity auto
    (the default) tries E first and falls back to N, which is harmless on a pty.
  * ASCII is sent with 8 data bits for the same reason (the standard 7E1 is refused).
  * pymodbus does not treat device id 0 as broadcast by itself: it waits for a reply
    unless no_response_expected=True is passed.
  * Exceptions come back as an ExceptionResponse (isError() true, exception_code, and
    function_code with 80H set), not as a Python exception; no reply at all raises
    ModbusIOException after the timeout.
  * 08H (diag_query_data) in RTU only decodes a reply with exactly 2 data bytes.
"""

import argparse
import inspect
import json
import logging
import sys
import time

try:
    from pymodbus.client import ModbusSerialClient

    try:
        from pymodbus import FramerType
    except ImportError:  # pymodbus < 3.7
        from pymodbus.framer import FramerType  # type: ignore
    import serial  # noqa: F401  (pyserial, needed by ModbusSerialClient)
except ImportError as e:
    print(
        f"pymodbus_master.py: cannot import pymodbus/pyserial ({e}); "
        "install them with: pip install pymodbus pyserial",
        file=sys.stderr,
    )
    sys.exit(2)

# Per model: the identification register 252FH and a register not in the map.
MODELS = {
    "f510": {"ident": 0x0510, "unmapped": 0x0039},
    "l510": {"ident": 0x0110, "unmapped": 0x0039},
    "a510": {"ident": 0x0A51, "unmapped": 0x003A},
    "e510": {"ident": 0x0E51, "unmapped": 0x0039},
}
# Largest 03H count in one frame (80-byte frame limit).
MAX_READ = {"rtu": 37, "ascii": 17}

FREQ = 0x2502  # frequency command, read-write, max E9FCH
FREQ_MIRROR = 0x2523  # read-only monitor copy of the frequency command
FREQ_MAX = 0xE9FC
MONITOR = 0x2520  # monitor block 2520H..252FH, read-only
IDENT = 0x252F

RESULTS = []


def report(op, ok, detail):
    rec = {"op": op, "ok": bool(ok), "detail": detail}
    RESULTS.append(rec)
    print(json.dumps(rec), flush=True)


def hexs(values):
    return "[" + ", ".join(f"0x{v:04X}" for v in values) + "]"


def unit_kw(method):
    """pymodbus renamed slave= to device_id= in 3.10; accept both."""
    params = inspect.signature(method).parameters
    return "device_id" if "device_id" in params else "slave"


class Master:
    def __init__(self, client, address):
        self.c = client
        self.address = address
        self.kw = unit_kw(client.read_holding_registers)

    def read(self, reg, count, address=None):
        kw = {self.kw: self.address if address is None else address}
        return self.c.read_holding_registers(reg, count=count, **kw)

    def write(self, reg, value, address=None, **extra):
        kw = {self.kw: self.address if address is None else address}
        return self.c.write_register(reg, value, **kw, **extra)

    def write_many(self, reg, values):
        return self.c.write_registers(reg, values, **{self.kw: self.address})

    def loop_back(self, data):
        return self.c.diag_query_data(data, **{self.kw: self.address})


def run_op(op, fn):
    """Runs fn() -> (ok, detail); an exception (no reply, bad frame) is a failure."""
    try:
        ok, detail = fn()
    except Exception as e:  # noqa: BLE001 - every pymodbus error is a failed operation
        ok, detail = False, f"{type(e).__name__}: {e}"
    report(op, ok, detail)


def expect_registers(what, rr, expected):
    if rr.isError():
        return False, f"{what}: expected {hexs(expected)}, got {rr}"
    got = list(rr.registers)
    return got == expected, f"{what} -> {hexs(got)}" + (
        "" if got == expected else f", expected {hexs(expected)}"
    )


def expect_exception(what, rr, function, code):
    if not rr.isError():
        return False, f"{what}: expected exception {code:02X}H, got normal reply {rr}"
    fc = getattr(rr, "function_code", None)
    ec = getattr(rr, "exception_code", None)
    ok = fc == (function | 0x80) and ec == code
    return ok, f"{what} -> exception {ec:02X}H (function {fc:02X}H)" + (
        "" if ok else f", expected exception {code:02X}H (function {function | 0x80:02X}H)"
    )


def connect(args):
    framer = FramerType.RTU if args.mode == "rtu" else FramerType.ASCII
    parities = ["E", "N"] if args.parity == "auto" else [args.parity]
    tried = []
    for parity in parities:
        client = ModbusSerialClient(
            args.port,
            framer=framer,
            baudrate=args.baud,
            bytesize=8,
            parity=parity,
            stopbits=1,
            timeout=args.timeout,
            retries=0,
        )
        if client.connect():
            note = f" (8{tried[-1]}1 refused: a pty has no parity)" if tried else ""
            report(
                "connect",
                True,
                f"{args.port} {args.mode} {args.baud} 8{parity}1{note}, pymodbus {pymodbus_version()}",
            )
            return client
        client.close()
        tried.append(parity)
    report("connect", False, f"cannot open {args.port} with parity {'/'.join(tried)}")
    return None


def pymodbus_version():
    try:
        import pymodbus

        return pymodbus.__version__
    except Exception:  # noqa: BLE001
        return "?"


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("port")
    ap.add_argument("mode", choices=["rtu", "ascii"])
    ap.add_argument("model", nargs="?", default="f510", choices=sorted(MODELS))
    ap.add_argument("--address", type=int, default=1)
    ap.add_argument("--baud", type=int, default=9600)
    ap.add_argument("--parity", choices=["auto", "E", "O", "N"], default="auto")
    ap.add_argument("--timeout", type=float, default=1.0, help="reply timeout in seconds")
    ap.add_argument("-v", "--verbose", action="store_true", help="pymodbus debug log on stderr")
    args = ap.parse_args()

    logging.basicConfig(stream=sys.stderr)
    logging.getLogger("pymodbus").setLevel(logging.DEBUG if args.verbose else logging.CRITICAL)

    model = MODELS[args.model]
    ident = model["ident"]
    client = connect(args)
    if client is not None:
        try:
            operations(Master(client, args.address), args, model, ident)
        finally:
            client.close()

    failures = [r for r in RESULTS if not r["ok"]]
    for r in failures:
        print(f"FAILED: {r['op']}: {r['detail']}", file=sys.stderr)
    return 1 if failures else 0


def operations(m, args, model, ident):
    # 03H: identification register.
    run_op("read_identification", lambda: expect_registers("03H 252FH x1", m.read(IDENT, 1), [ident]))

    # 03H: the whole monitor block 2520H..252FH (16 registers, within both modes' limits).
    def monitor_block():
        rr = m.read(MONITOR, 16)
        if rr.isError():
            return False, f"03H 2520H x16: {rr}"
        regs = list(rr.registers)
        ok = len(regs) == 16 and regs[-1] == ident
        return ok, f"03H 2520H x16 -> {hexs(regs)}" + (
            "" if ok else f", expected 16 registers ending with 0x{ident:04X}"
        )

    run_op("read_monitor_block", monitor_block)

    # 06H: frequency command, echoed, read back, mirrored into 2523H.
    freq = 0x1770  # 60.00 Hz

    def write_single():
        rr = m.write(FREQ, freq)
        if rr.isError():
            return False, f"06H 2502H=0x{freq:04X}: {rr}"
        got = (rr.address, rr.registers[0] if rr.registers else None)
        ok = got == (FREQ, freq)
        return ok, f"06H 2502H=0x{freq:04X} -> echo register 0x{rr.address:04X} value {hexs(rr.registers)}"

    run_op("write_single_frequency", write_single)
    run_op("readback_frequency", lambda: expect_registers("03H 2502H x1", m.read(FREQ, 1), [freq]))
    run_op("readback_frequency_mirror", lambda: expect_registers("03H 2523H x1", m.read(FREQ_MIRROR, 1), [freq]))

    # 10H: two registers of parameter group 0, read back.
    values = [0x1234, 0xABCD]

    def write_multiple():
        rr = m.write_many(0x0000, values)
        if rr.isError():
            return False, f"10H 0000H x2: {rr}"
        ok = rr.address == 0x0000 and rr.count == 2
        return ok, f"10H 0000H={hexs(values)} -> start 0x{rr.address:04X} count {rr.count}"

    run_op("write_multiple", write_multiple)
    run_op("readback_multiple", lambda: expect_registers("03H 0000H x2", m.read(0x0000, 2), values))

    # 08H: loop-back, test code 0000H with two arbitrary data bytes, echoed. (mbpoll has no
    # 08H at all.) Keep it at two bytes: pymodbus 3.16's RTU framer sizes an 08H response as
    # 8 bytes, so it reports "No response received" for a longer (correct) echo; ASCII,
    # delimited by CR LF, would take any length.
    data = b"\xa5\x37"

    def loop_back():
        rr = m.loop_back(data)
        if rr.isError():
            return False, f"08H 0000H data {data.hex().upper()}: {rr}"
        sub = getattr(rr, "sub_function_code", None)
        msg = rr.message if isinstance(rr.message, bytes) else bytes(rr.message or b"")
        ok = sub == 0 and msg == data
        return ok, f"08H 0000H data {data.hex().upper()} -> test code {sub:04X}H data {msg.hex().upper()}"

    run_op("loop_back", loop_back)

    # Exceptions.
    unmapped = model["unmapped"]
    run_op(
        "exception_unmapped_register",
        lambda: expect_exception(f"03H {unmapped:04X}H x1", m.read(unmapped, 1), 0x03, 0x02),
    )
    run_op(
        "exception_read_only_write",
        lambda: expect_exception("06H 2520H=0x0001", m.write(MONITOR, 0x0001), 0x06, 0x02),
    )
    run_op(
        "exception_out_of_range",
        lambda: expect_exception(f"06H 2502H=0x{FREQ_MAX + 1:04X}", m.write(FREQ, FREQ_MAX + 1), 0x06, 0x04),
    )
    run_op(
        "readback_after_rejected_write",
        lambda: expect_registers("03H 2502H x1 (unchanged)", m.read(FREQ, 1), [freq]),
    )
    too_many = MAX_READ[args.mode] + 1
    run_op(
        "exception_count",
        lambda: expect_exception(f"03H 0000H x{too_many}", m.read(0x0000, too_many), 0x03, 0x03),
    )

    # Broadcast: executed, never answered (pymodbus must be told not to wait).
    bvalue = 0x0BEE

    def broadcast():
        rr = m.write(0x0002, bvalue, address=0, no_response_expected=True)
        time.sleep(0.1)  # the drive executes it after its response time
        back = m.read(0x0002, 1)
        if back.isError():
            return False, f"06H broadcast 0002H=0x{bvalue:04X}, read back: {back}"
        ok = list(back.registers) == [bvalue]
        return ok, f"06H broadcast 0002H=0x{bvalue:04X} -> no reply ({rr}), read back {hexs(back.registers)}"

    run_op("broadcast_write", broadcast)

    # Another node address: no reply at all (pymodbus raises ModbusIOException after timeout).
    other = 2 if args.address != 2 else 3

    def other_address():
        try:
            rr = m.read(IDENT, 1, address=other)
        except Exception as e:  # noqa: BLE001
            return True, f"03H to node {other:02X} -> no reply ({type(e).__name__})"
        if rr.isError() and getattr(rr, "exception_code", 0) == 0:
            return True, f"03H to node {other:02X} -> no reply ({rr})"
        return False, f"03H to node {other:02X} -> unexpected reply {rr}"

    run_op("silent_for_other_address", other_address)


if __name__ == "__main__":
    sys.exit(main())
