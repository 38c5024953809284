#!/usr/bin/env python3
"""A generic Modbus TCP server from pymodbus: one unit with 65535 holding registers
(0000H..FFFEH), all zero, and nothing TECO-specific; pymodbus's defaults otherwise (a unit
id it does not have, unit 0 included, is answered with exception 0BH, gateway target
device failed to respond).

The conformance runner checks it as an F510 through `--tcp --framing mbap` to show that
the Modbus TCP gateway link completes against a server that nobody here wrote.

    pymodbus_tcp_server.py PORT [--unit 1[,2,...]] [--host 127.0.0.1]

With several unit ids it serves one unit at each, each with its own registers.
"""
import argparse
import logging
import sys

from pymodbus.datastore import (
    ModbusDeviceContext,
    ModbusSequentialDataBlock,
    ModbusServerContext,
)
from pymodbus.server import StartTcpServer


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("port", type=int)
    p.add_argument("--unit", default="1", help="unit id, or several: 1,2")
    p.add_argument("--host", default="127.0.0.1")
    a = p.parse_args()
    # pymodbus logs every missing unit id as an error; the runner asks for some on purpose.
    logging.basicConfig(level=logging.CRITICAL, stream=sys.stderr)
    # pymodbus 3.16 numbers data blocks from 1 (protocol address 0 is block address 1)
    # and takes at most 65535 registers: protocol addresses 0000H..FFFEH.
    units = [int(u) for u in a.unit.split(",")]
    devices = {
        u: ModbusDeviceContext(hr=ModbusSequentialDataBlock(1, [0] * 65535)) for u in units
    }
    context = ModbusServerContext(devices=devices, single=False)
    print(
        f"pymodbus generic TCP server on {a.host}:{a.port} (units {a.unit})",
        file=sys.stderr,
        flush=True,
    )
    StartTcpServer(context=context, address=(a.host, a.port))
    return 0


if __name__ == "__main__":
    sys.exit(main())
