#!/usr/bin/env python3
"""Master adapter for the mbpoll program (the master adapter protocol, role "master", of
../PROTOCOL.md): every operation runs ``mbpoll`` once (``-1``) and the answer is read from
its output and exit code. The adapter never touches the line itself.

* open only records the settings: ``-m rtu -b BAUD -P none|even|odd -d BITS -s STOP
  -o TIMEOUT_S`` and the pty path (or ``-m tcp -p PORT HOST`` for ``mbap``). mbpoll has no
  ASCII and no retries (``open`` answers ``retries: 0`` whatever was asked); its time-out
  is 0.01..10 s (a ``timeout_ms`` outside is brought inside, and the answer says so).
* read: ``mbpoll ... -a UNIT -0 -1 -t 4:hex -r START -c COUNT PATH`` and the ``[ref]: 0xNNNN``
  lines of its output.
* write-single: ``mbpoll ... -t 4 -r REG PATH VALUE`` (one value: mbpoll sends 06H);
  write-multiple: ``... PATH V1 V2 ...`` (10H).
* broadcast: mbpoll refuses address 0 in RTU ("slave address out of range"), so the
  adapter does not announce it.
* loop-back: not offered by mbpoll.

A failed call exits 1 with ``Read output (holding) register failed: <libmodbus's
modbus_strerror text>`` (or ``Write ...``) on stderr; the text is mapped back to the
exception code or error kind as libmodbus words them.

The protocol's loop (reading requests, dispatching them, writing answers), the hello and
the shapes of the answers are ../master_common.py's, shared by the Python master
adapters; this file keeps what is mbpoll's own.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys

# The loop, hello and answers the Python master adapters share (adapters/master_common.py);
# appended, so that this folder's neighbours never shadow an installed package.
sys.path.append(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from master_common import (  # noqa: E402
    done, error, exception, hello_answer, ops_of, protocol_stream, raised, refuse_hello, serve, values,
)

ADAPTER = "mbpoll-master"
OUT = protocol_stream()

# libmodbus 3.1.6 modbus_strerror texts (src/modbus.c) back to the exception code.
EXCEPTION_OF_TEXT = {
    "Illegal function": 0x01,
    "Illegal data address": 0x02,
    "Illegal data value": 0x03,
    "Slave device or server failure": 0x04,
    "Acknowledge": 0x05,
    "Slave device or server is busy": 0x06,
    "Negative acknowledge": 0x07,
    "Memory parity error": 0x08,
    "Gateway path unavailable": 0x0A,
    "Target device failed to respond": 0x0B,
}
KIND_OF_TEXT = {
    "Connection timed out": "timeout",
    "Invalid CRC": "checksum",
    "Invalid data": "invalid-frame",
    "Invalid exception code": "invalid-frame",
    "Unknown exception code": "invalid-frame",
    "Too many data": "invalid-frame",
    "Response not from requested slave": "invalid-frame",
}

settings: dict | None = None


def mbpoll_version() -> str:
    try:
        out = subprocess.run(["mbpoll", "-V"], capture_output=True, text=True, timeout=5)
        return (out.stdout or out.stderr).strip() or "?"
    except (OSError, subprocess.SubprocessError):
        return "not installed"


def op_hello(req: dict) -> dict:
    refused = refuse_hello(req)
    if refused is None and shutil.which("mbpoll") is None:
        refused = {"ok": False, "error": "mbpoll is not on the PATH (Debian package mbpoll)"}
    return refused or hello_answer(
        ADAPTER, "mbpoll", mbpoll_version(),
        supports=["read", "write-single", "write-multiple"],
        lines=["pty", "mbap"], modes=["rtu"])


def op_open(req: dict) -> dict:
    global settings
    settings = None
    if req.get("mode", "rtu") != "rtu":
        return {"ok": False, "error": "unsupported", "detail": "mbpoll has no ASCII"}
    # mbpoll's -o is 0.01..10 s and it has no retries: it runs with the nearest timeout and
    # 0 retries, whatever was asked (the gate judges with what this answer reports).
    ms = min(max(int(req.get("timeout_ms", 1000)), 10), 10000)
    line = req.get("line") or {}
    if line.get("kind") == "pty":
        parity = {"N": "none", "E": "even", "O": "odd"}[str(req.get("parity", "N"))[:1].upper()]
        args = ["-m", "rtu", "-b", str(int(req.get("baud", 19200))), "-P", parity,
                "-d", str(int(req.get("data_bits", 8))), "-s", str(int(req.get("stop_bits", 1)))]
        target = line["path"]
    elif line.get("kind") == "mbap":
        args = ["-m", "tcp", "-p", str(int(line["port"]))]
        target = str(line["host"])
    else:
        return {"ok": False, "error": "unsupported", "detail": f"line {line.get('kind')}"}
    args += ["-o", f"{ms / 1000:.2f}"]
    settings = {"args": args, "target": target, "timeout_ms": ms}
    return {"ok": True, "timeout_ms": ms, "retries": 0}


def run(extra: list[str], values: list[str] | None = None) -> tuple[int, str, str]:
    if settings is None:
        raise RuntimeError("not open")
    cmd = ["mbpoll", *settings["args"], *extra, settings["target"]]
    if values:
        cmd += ["--", *values]
    p = subprocess.run(cmd, capture_output=True, text=True, timeout=settings["timeout_ms"] / 1000 + 10)
    return p.returncode, p.stdout, p.stderr


def failed(rc: int, stdout: str, stderr: str) -> dict:
    m = re.search(r"failed: (.+)", stderr)
    text = m.group(1).strip() if m else (stderr.strip().splitlines() or [f"exit code {rc}"])[-1]
    if text in EXCEPTION_OF_TEXT:
        return exception(EXCEPTION_OF_TEXT[text], message=text)
    return error(KIND_OF_TEXT.get(text, "other"), f"{text} (exit code {rc})")


def common(req: dict) -> list[str]:
    return ["-a", str(int(req["unit"])), "-0", "-1"]


def op_read(req: dict) -> dict:
    count = int(req["count"])
    rc, out, err = run(common(req) + ["-t", "4:hex", "-r", str(int(req["start"], 16)), "-c", str(count)])
    if rc != 0:
        return failed(rc, out, err)
    registers = re.findall(r"^\[\d+\]:\s*0x([0-9A-Fa-f]{4})\s*$", out, re.M)
    if not registers:
        return raised("exit 0", f"mbpoll exited 0 with no values: {out.strip()[-200:]!r}")
    return values(int(v, 16) for v in registers)


def written(rc: int, out: str, err: str) -> dict:
    if rc != 0:
        return failed(rc, out, err)
    m = re.search(r"Written (\d+) references", out)
    return done(echo={"count": int(m.group(1))}) if m else done()


def op_write_single(req: dict) -> dict:
    rc, out, err = run(common(req) + ["-t", "4", "-r", str(int(req["register"], 16))],
                       [str(int(req["value"], 16))])
    return written(rc, out, err)


def op_write_multiple(req: dict) -> dict:
    rc, out, err = run(common(req) + ["-t", "4", "-r", str(int(req["start"], 16))],
                       [str(int(v, 16)) for v in req["values"]])
    return written(rc, out, err)


def op_loop_back(_req: dict) -> dict:
    return {"ok": False, "error": "unsupported", "detail": "mbpoll has no 08H"}


def op_close(_req: dict) -> dict:
    global settings
    settings = None
    return {"ok": True}


if __name__ == "__main__":
    sys.exit(serve(ops_of(globals()), ADAPTER, OUT))
