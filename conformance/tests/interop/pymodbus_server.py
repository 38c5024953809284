#!/usr/bin/env python3
"""A generic Modbus RTU/ASCII slave from pymodbus, on a serial port (a pseudo-terminal in
the tests): one node with 65535 holding registers (0000H..FFFEH), all zero, and nothing TECO-specific.

The conformance runner checks it as an F510 to show that it completes against a device
that nobody here wrote, reports that device's deviations from the F510 manual, and
neither panics nor hangs.

    pymodbus_server.py PORT [rtu|ascii] [--address 1[,2,...]] [--registers N]
                       [--blocks FIRST-LAST[,FIRST-LAST...]]

--registers N serves only 0000H..N-1 (a generic device without, say, the registers from
1000H up: every read beyond is refused with exception 02H).

--blocks 0000-0FFF,2500-252F (hex) serves those blocks of holding registers only, each
its own pymodbus block: a read that leaves a block is refused with exception 02H (the
device of issue 34, for `model learn`).

With several addresses it serves one node at each, each with its own registers (several
drives on one bus, for `check -a 1,2`).
"""
import argparse
import logging
import sys

from pymodbus import FramerType
from pymodbus.datastore import (
    ModbusDeviceContext,
    ModbusSequentialDataBlock,
    ModbusSparseDataBlock,
    ModbusServerContext,
)
from pymodbus.server import StartSerialServer


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("port")
    p.add_argument("mode", nargs="?", default="rtu", choices=["rtu", "ascii"])
    p.add_argument("--address", default="1", help="node address, or several: 1,2")
    p.add_argument("--registers", type=int, default=65535, help="holding registers 0000H..N-1")
    p.add_argument("--blocks", help="holding register blocks, hex: 0000-0FFF,2500-252F")
    a = p.parse_args()
    logging.basicConfig(level=logging.WARNING, stream=sys.stderr)
    # pymodbus 3.16 numbers data blocks from 1 (protocol address 0 is block address 1)
    # and takes at most 65535 registers: protocol addresses 0000H..FFFEH.
    nodes = [int(n) for n in a.address.split(",")]
    def holding():
        if a.blocks:
            spans = [[int(x, 16) for x in b.split("-")] for b in a.blocks.split(",")]
            # A sparse block's keys are protocol addresses; a list value is a block.
            return ModbusSparseDataBlock({f: [0] * (l - f + 1) for f, l in spans})
        return ModbusSequentialDataBlock(1, [0] * min(a.registers, 65535))

    devices = {n: ModbusDeviceContext(hr=holding()) for n in nodes}
    context = ModbusServerContext(devices=devices, single=False)
    framer = FramerType.RTU if a.mode == "rtu" else FramerType.ASCII
    print(f"pymodbus generic server on {a.port} ({a.mode}, nodes {a.address})", file=sys.stderr, flush=True)
    # 8N1: pyserial on a Linux pseudo-terminal refuses a parity-only change (EINVAL).
    StartSerialServer(
        context=context,
        framer=framer,
        port=a.port,
        baudrate=9600,
        bytesize=8,
        parity="N",
        stopbits=1,
        timeout=0.05,
    )
    return 0


if __name__ == "__main__":
    sys.exit(main())
