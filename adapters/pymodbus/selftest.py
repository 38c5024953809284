#!/usr/bin/env python3
"""Self-test of the pymodbus adapter: drives adapter.py over its stdin/stdout.

Prints one line per item:

  PASS                      the adapter answered as expected
  PYMODBUS DIFFERS: ...     pymodbus itself behaves differently from what the
                            protocol / Modbus expects, and the adapter reports
                            that faithfully (a finding about pymodbus, not a
                            failure of the adapter)
  FAIL                      anything else

Exit status 0 only if nothing FAILed.
"""

from __future__ import annotations

import json
import os
import queue
import subprocess
import sys
import threading

HERE = os.path.dirname(os.path.abspath(__file__))
ADAPTER = os.path.join(HERE, "adapter.py")
TIMEOUT = 10.0

# The CRC the Python adapters share (adapters/adapter_common.py), to build probe frames.
sys.path.append(os.path.dirname(HERE))
from adapter_common import crc16  # noqa: E402


# --------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------


def ascii_hex(text: str) -> str:
    """An ASCII frame as the hex codes of its characters."""
    return " ".join(f"{ord(c):02X}" for c in text)


def norm_hex(text) -> str:
    return " ".join(str(text).upper().split())


def rtu(body_hex: str) -> str:
    body = bytes.fromhex(body_hex)
    return " ".join(f"{b:02X}" for b in body + crc16(body))


def ascii_frame(body_hex: str) -> str:
    body = bytes.fromhex(body_hex)
    lrc = (-sum(body)) & 0xFF
    return ascii_hex(":" + body.hex().upper() + f"{lrc:02X}" + "\r\n")


def norm(value):
    """Normalise for comparison: hex strings compared case-insensitively."""
    if isinstance(value, str):
        return norm_hex(value)
    if isinstance(value, list):
        return [norm(v) for v in value]
    if isinstance(value, dict):
        return {k: norm(v) for k, v in value.items()}
    return value


def message_matches(expected: dict, got) -> tuple[bool, str]:
    if not isinstance(got, dict):
        return False, f"no message: {got!r}"
    for key in ("address", "function", "kind"):
        if norm(expected[key]) != norm(got.get(key)):
            return False, f"{key}: expected {expected[key]!r}, got {got.get(key)!r}"
    gf = got.get("fields") or {}
    for key, val in expected["fields"].items():
        if norm(val) != norm(gf.get(key)):
            return False, f"fields.{key}: expected {val!r}, got {gf.get(key)!r}"
    return True, ""


# --------------------------------------------------------------------------
# adapter process
# --------------------------------------------------------------------------


class Adapter:
    def __init__(self) -> None:
        self.proc = subprocess.Popen(
            [sys.executable, ADAPTER],
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
        )
        self.lines: queue.Queue = queue.Queue()
        self.stderr: list[str] = []
        threading.Thread(target=self._read_out, daemon=True).start()
        threading.Thread(target=self._read_err, daemon=True).start()
        self.next_id = 0

    def _read_out(self) -> None:
        for raw in self.proc.stdout:
            self.lines.put(raw.decode("utf-8", "replace").rstrip("\n"))
        self.lines.put(None)

    def _read_err(self) -> None:
        for raw in self.proc.stderr:
            self.stderr.append(raw.decode("utf-8", "replace").rstrip("\n"))

    def send_line(self, line: str) -> None:
        self.proc.stdin.write(line.encode() + b"\n")
        self.proc.stdin.flush()

    def read_answer(self):
        try:
            line = self.lines.get(timeout=TIMEOUT)
        except queue.Empty:
            return {"_error": "timeout"}
        if line is None:
            return {"_error": f"adapter exited (rc={self.proc.poll()})"}
        try:
            return json.loads(line)
        except ValueError:
            return {"_error": f"answer not JSON: {line!r}"}

    def call(self, request: dict):
        rid = self.next_id
        self.next_id += 1
        self.send_line(json.dumps({"id": rid, **request}))
        ans = self.read_answer()
        if "_error" not in ans and ans.get("id") != rid:
            return {"_error": f"answer id {ans.get('id')!r}, expected {rid}: {ans}"}
        return ans

    def close(self) -> int:
        try:
            self.proc.stdin.close()
        except OSError:
            pass
        try:
            return self.proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            return self.proc.wait()


# --------------------------------------------------------------------------
# checks
# --------------------------------------------------------------------------


def expect_message(expected):
    def check(ans):
        if ans.get("ok") is not True:
            return False, f"ok is not true: {ans}"
        if ans.get("accepted") is not True:
            return False, f"not accepted: {ans.get('reason')!r}"
        return message_matches(expected, ans.get("message"))

    return check


def expect_rejected(ans):
    if ans.get("ok") is not True:
        return False, f"ok is not true: {ans}"
    if ans.get("accepted") is not False:
        return False, f"accepted: {ans.get('message')}"
    if not ans.get("reason"):
        return False, "no reason given"
    return True, ""


def expect_frame(frame):
    def check(ans):
        if ans.get("ok") is not True:
            return False, f"ok is not true: {ans}"
        if norm_hex(ans.get("frame", "")) != norm_hex(frame):
            return False, f"frame {ans.get('frame')!r}, expected {frame!r}"
        return True, ""

    return check


def expect_key(key, value):
    def check(ans):
        if ans.get("ok") is not True:
            return False, f"ok is not true: {ans}"
        if norm(ans.get(key)) != norm(value):
            return False, f"{key} {ans.get(key)!r}, expected {value!r}"
        return True, ""

    return check


def expect_unsupported(ans):
    if ans.get("ok") is False and ans.get("error") == "unsupported":
        return True, ""
    return False, f"expected ok false / unsupported, got {ans}"


def expect_hello(ans):
    if ans.get("ok") is not True or ans.get("protocol") != 1:
        return False, f"bad hello answer {ans}"
    if ans.get("implementation") != "pymodbus" or ans.get("version") != "3.16.1":
        return False, f"implementation/version {ans.get('implementation')!r} {ans.get('version')!r}"
    missing = {"decode", "encode", "crc", "lrc"} - set(ans.get("supports") or [])
    if missing:
        return False, f"supports lacks {sorted(missing)}"
    return True, ""


# Deviation predicates: recognise what pymodbus 3.16.1 is known to do.
def is_accepted(ans):
    return ans.get("ok") is True and ans.get("accepted") is True


def is_rejected(ans):
    return ans.get("ok") is True and ans.get("accepted") is False


def accepted_with(expected):
    def pred(ans):
        return is_accepted(ans) and message_matches(expected, ans.get("message"))[0]

    return pred


def error_contains(text):
    def pred(ans):
        return ans.get("ok") is False and text in str(ans.get("error", ""))

    return pred


# --------------------------------------------------------------------------
# the conversation
# --------------------------------------------------------------------------

M_READ_REQ = {"address": "01", "function": "03", "kind": "read-request",
              "fields": {"start": "0123", "count": 1}}
M_READ_RESP = {"address": "01", "function": "03", "kind": "read-response",
               "fields": {"byte_count": 2, "values": ["1770"]}}
M_WRITE_SINGLE = {"address": "01", "function": "06", "kind": "write-single",
                  "fields": {"register": "0102", "value": "1770"}}
M_LOOP = {"address": "01", "function": "08", "kind": "loop-back",
          "fields": {"test_code": "0000", "data": "A5 37"}}
M_WM_REQ = {"address": "01", "function": "10", "kind": "write-multiple-request",
            "fields": {"start": "0101", "count": 2, "byte_count": 4, "values": ["0001", "1770"]}}
M_WM_RESP = {"address": "01", "function": "10", "kind": "write-multiple-response",
             "fields": {"start": "0101", "count": 2}}
M_EXC = {"address": "01", "function": "83", "kind": "exception",
         "fields": {"exception_function": "03", "code": "02"}}

ASCII_READ = ascii_hex(":010301230001D7\r\n")

# (name, mode, direction, frame, expected message)
ROUND_TRIPS = [
    ("RTU read request", "rtu", "request", "01 03 01 23 00 01 74 3C", M_READ_REQ),
    ("RTU read response", "rtu", "response", "01 03 02 17 70 B6 50", M_READ_RESP),
    ("RTU write-single request", "rtu", "request", "01 06 01 02 17 70 27 E2", M_WRITE_SINGLE),
    ("RTU write-single response", "rtu", "response", "01 06 01 02 17 70 27 E2", M_WRITE_SINGLE),
    ("RTU loop-back request", "rtu", "request", "01 08 00 00 A5 37 DA 8D", M_LOOP),
    ("RTU loop-back response", "rtu", "response", "01 08 00 00 A5 37 DA 8D", M_LOOP),
    ("RTU write-multiple request", "rtu", "request", "01 10 01 01 00 02 04 00 01 17 70 60 27", M_WM_REQ),
    ("RTU write-multiple response", "rtu", "response", "01 10 01 01 00 02 11 F4", M_WM_RESP),
    ("RTU exception response", "rtu", "response", "01 83 02 C0 F1", M_EXC),
    ("ASCII read request", "ascii", "request", ASCII_READ, M_READ_REQ),
]


def build_items():
    """Each item: (name, kind, payload, check, deviation or None).

    kind "call": payload is a request dict; "raw": payload is a raw line, the
    answer is read without id matching.
    deviation: (predicate, note) recognising pymodbus's known behaviour.
    """
    items = [("hello", "call", {"op": "hello", "protocol": 1}, expect_hello, None)]
    for name, mode, direction, frame, msg in ROUND_TRIPS:
        items.append((f"decode {name}", "call",
                       {"op": "decode", "mode": mode, "direction": direction, "frame": frame},
                       expect_message(msg), None))
    items += [
        ("decode RTU read response, bad CRC", "call",
         {"op": "decode", "mode": "rtu", "direction": "response", "frame": "01 03 02 17 70 AF 82"},
         expect_rejected, None),
        ("decode ASCII read request, wrong LRC", "call",
         {"op": "decode", "mode": "ascii", "direction": "request",
          "frame": ascii_hex(":010301230001D8\r\n")},
         expect_rejected, None),
    ]
    for name, mode, direction, frame, msg in ROUND_TRIPS:
        items.append((f"encode {name}", "call",
                      {"op": "encode", "mode": mode, "direction": direction, "message": msg},
                      expect_frame(frame), None))
    items += [
        ("encode ASCII write-single request (PROTOCOL.md example)", "call",
         {"op": "encode", "mode": "ascii", "direction": "request", "message": M_WRITE_SINGLE},
         expect_frame("3A 30 31 30 36 30 31 30 32 31 37 37 30 36 46 0D 0A"), None),
        ("crc 01 03 01 23 00 01", "call", {"op": "crc", "data": "01 03 01 23 00 01"},
         expect_key("crc", "3C74"), None),
        ("lrc 01 03 01 00 0A", "call", {"op": "lrc", "data": "01 03 01 00 0A"},
         expect_key("lrc", "F1"), None),
        ("unknown op", "call", {"op": "frobnicate"}, expect_unsupported, None),
        ("hello with protocol 2 refused", "call", {"op": "hello", "protocol": 2},
         lambda a: (a.get("ok") is False, str(a)), None),
        ("garbage line 'not json' answered with id null, ok false", "raw", "not json",
         lambda a: (a.get("ok") is False and a.get("id") is None and "_error" not in a, str(a)),
         None),
        ("next valid request after garbage still works", "call",
         {"op": "crc", "data": "01 03 01 23 00 01"}, expect_key("crc", "3C74"), None),
        ("bad hex in a request is an error, not a crash", "call",
         {"op": "decode", "mode": "rtu", "direction": "request", "frame": "01 0G"},
         lambda a: (a.get("ok") is False and "_error" not in a, str(a)), None),
        ("still alive after bad hex", "call", {"op": "lrc", "data": "01 03 01 00 0A"},
         expect_key("lrc", "F1"), None),
    ]

    # ---- probes: what Modbus / the gate's codec expect, and what pymodbus does
    items += [
        ("probe: RTU frame with a trailing byte after a valid frame is rejected", "call",
         {"op": "decode", "mode": "rtu", "direction": "request", "frame": "01 03 01 23 00 01 74 3C 00"},
         expect_rejected,
         (accepted_with(M_READ_REQ),
          "FramerRTU takes the frame size from the function code (8 for 03H request), checks "
          "the CRC there and silently discards the extra byte: accepted")),
        ("probe: RTU 08H loop-back with 4 data bytes is accepted", "call",
         {"op": "decode", "mode": "rtu", "direction": "request", "frame": rtu("01 08 00 00 A5 37 12 34")},
         expect_message({"address": "01", "function": "08", "kind": "loop-back",
                         "fields": {"test_code": "0000", "data": "A5 37 12 34"}}),
         (is_rejected,
          "DiagnosticBase.rtu_frame_size is fixed at 8, so only 2 data bytes fit; a longer "
          "loop-back frame fails the CRC check at byte 6: rejected")),
        ("probe: RTU 08H with test code 0005 (not in pymodbus's table) is accepted", "call",
         {"op": "decode", "mode": "rtu", "direction": "request", "frame": rtu("01 08 00 05 00 00")},
         expect_message({"address": "01", "function": "08", "kind": "loop-back",
                         "fields": {"test_code": "0005", "data": "00 00"}}),
         (is_rejected,
          "the RTU framer finds no class for sub-function 0005 and keeps hunting: rejected "
          "('Frame - not ready'); the same PDU in ASCII is decoded")),
        ("probe: RTU read request with count 0 is a well-formed frame (accepted)", "call",
         {"op": "decode", "mode": "rtu", "direction": "request", "frame": rtu("01 03 01 23 00 00")},
         expect_message({"address": "01", "function": "03", "kind": "read-request",
                         "fields": {"start": "0123", "count": 0}}),
         (is_rejected,
          "ReadHoldingRegistersRequest.decode raises on count outside 1..125, the frame is "
          "refused ('Unable to decode request'); a pymodbus server then answers 80H/01H "
          "instead of 83H/03H")),
        ("probe: RTU read response with odd byte count 3 is rejected", "call",
         {"op": "decode", "mode": "rtu", "direction": "response", "frame": rtu("01 03 03 17 70 00")},
         expect_rejected,
         (accepted_with({"address": "01", "function": "03", "kind": "read-response",
                         "fields": {"values": ["1770"]}}),
          "accepted; the odd last byte is silently dropped (values [1770])")),
        ("probe: RTU 10H request with count 3 but byte count 4 is rejected", "call",
         {"op": "decode", "mode": "rtu", "direction": "request",
          "frame": rtu("01 10 01 01 00 03 04 00 01 17 70")},
         expect_rejected,
         (accepted_with({"address": "01", "function": "10", "kind": "write-multiple-request",
                         "fields": {"count": 3, "byte_count": 4}}),
          "the decoder accepts it (its server later answers exception 03)")),
        ("probe: ASCII read request with an extra data byte is rejected", "call",
         {"op": "decode", "mode": "ascii", "direction": "request",
          "frame": ascii_frame("01 03 01 23 00 01 FF")},
         expect_rejected,
         (accepted_with(M_READ_REQ),
          "FramerAscii does not check the PDU length: accepted, extra byte ignored")),
        ("probe: ASCII frame with non-hex address characters is rejected", "call",
         {"op": "decode", "mode": "ascii", "direction": "request",
          "frame": ascii_hex(":ZZ0301230001D7\r\n")},
         expect_rejected,
         (error_contains("ValueError"),
          "FramerAscii.decode parses the address outside its try block: ValueError escapes "
          "the framer (adapter answers ok:false, the gate shows ERROR)")),
        ("probe: ASCII 08H test code 0001 with 3 data bytes keeps the data", "call",
         {"op": "decode", "mode": "ascii", "direction": "request",
          "frame": ascii_frame("01 08 00 01 00 00 07")},
         expect_message({"address": "01", "function": "08", "kind": "loop-back",
                         "fields": {"test_code": "0001", "data": "00 00 07"}}),
         (accepted_with({"address": "01", "function": "08", "kind": "loop-back",
                         "fields": {"test_code": "0001", "data": "00 00 07 30"}}),
          "DiagnosticBase.decode pads odd data with b'0' (30H, not 00H): data 00 00 07 30")),
    ]
    return items


def main() -> int:
    adapter = Adapter()
    counts = {"PASS": 0, "FAIL": 0, "DIFFERS": 0}
    differs = []
    try:
        for name, how, payload, check, deviation in build_items():
            if how == "raw":
                adapter.send_line(payload)
                ans = adapter.read_answer()
            else:
                ans = adapter.call(payload)
            if "_error" in ans:
                ok, detail = False, ans["_error"]
            else:
                ok, detail = check(ans)
            if ok:
                counts["PASS"] += 1
                print(f"PASS  {name}")
            elif deviation and "_error" not in ans and deviation[0](ans):
                counts["DIFFERS"] += 1
                differs.append(name)
                print(f"PYMODBUS DIFFERS: {name}\n      {deviation[1]}\n      answer: {json.dumps(ans)}")
            else:
                counts["FAIL"] += 1
                print(f"FAIL  {name}\n      {detail}\n      answer: {json.dumps(ans)}")
    finally:
        rc = adapter.close()
    if rc != 0:
        counts["FAIL"] += 1
        print(f"FAIL  adapter exit status {rc} at end of input")
    else:
        print("PASS  adapter exits 0 at end of input")
        counts["PASS"] += 1
    if os.environ.get("SELFTEST_SHOW_STDERR"):
        print("\n--- adapter stderr ---")
        print("\n".join(adapter.stderr))
    print(f"\n{counts['PASS']} passed, {counts['DIFFERS']} pymodbus deviations, {counts['FAIL']} failed")
    return 0 if counts["FAIL"] == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
