#!/usr/bin/env python3
"""pymodbus's simulator serving a device described here: the JSON that `conformance model
export --to pymodbus-sim` wrote, loaded as pymodbus.simulator loads it
(`ModbusSimulatorContext(device_list[DEVICE])` in a `ModbusServerContext`, the server of
`server_list[SERVER]`), without its web page, on a serial port (a pseudo-terminal in the
tests).

    pymodbus_sim_server.py SIM.json PORT [--server server] [--device ID]

The port and parity replace the file's: pyserial on a Linux pseudo-terminal refuses a
parity (EINVAL), so the line is 8N1.
"""
import argparse
import asyncio
import json
import logging
import sys

from pymodbus.datastore import ModbusServerContext, ModbusSimulatorContext
from pymodbus.server import ModbusSerialServer


async def serve(a) -> None:
    with open(a.sim, encoding="utf-8") as f:
        setup = json.load(f)
    server = dict(setup["server_list"][a.server])
    device_id = a.device or next(iter(setup["device_list"]))
    context = ModbusSimulatorContext(setup["device_list"][device_id], None)
    if "device_id" in server:
        datastore = ModbusServerContext(devices={int(server.pop("device_id")): context}, single=False)
    else:
        datastore = ModbusServerContext(devices=context, single=True)
    server.pop("comm")
    framer = server.pop("framer")
    server["port"] = a.port
    server["parity"] = "N"
    print(f"pymodbus simulator serving {device_id} on {a.port}", file=sys.stderr, flush=True)
    s = ModbusSerialServer(framer=framer, context=datastore, **server)
    await s.serve_forever()


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__)
    p.add_argument("sim")
    p.add_argument("port")
    p.add_argument("--server", default="server")
    p.add_argument("--device")
    a = p.parse_args()
    logging.basicConfig(level=logging.ERROR, stream=sys.stderr)
    asyncio.run(serve(a))
    return 0


if __name__ == "__main__":
    sys.exit(main())
