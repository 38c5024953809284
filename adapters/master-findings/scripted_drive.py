#!/usr/bin/env python3
"""Direct experiment: a scripted drive on a pty pair drives a master adapter through one
fault per case, followed by a normal read (recovery). Every read reply carries a tag
(A000H + 10H * request number + i), so a stale or shifted reply is seen in the values.

usage: adapters/master-findings/scripted_drive.py MODE TIMEOUT_MS "ADAPTER CMD" [case...]
"""
import json, os, select, subprocess, sys, termios, threading, time, tty

MODE, TMO, CMD = sys.argv[1], int(sys.argv[2]), sys.argv[3]
ONLY = sys.argv[4:]

# The CRC the Python adapters share (adapters/adapter_common.py), to build the frames.
sys.path.append(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
from adapter_common import crc16  # noqa: E402

def lrc(data):
    return (-sum(data)) & 0xFF

def frame(pdu_with_addr, bad=False):
    if MODE == "rtu":
        c = crc16(pdu_with_addr)
        if bad:
            c = bytes([c[0] ^ 0xFF, c[1]])
        return pdu_with_addr + c
    l = lrc(pdu_with_addr) ^ (0xFF if bad else 0)
    return b":" + (pdu_with_addr + bytes([l])).hex().upper().encode() + b"\r\n"

master, slave = os.openpty()
tty.setraw(master); tty.setraw(slave)
path = os.ttyname(slave)
if os.environ.get("HOLD_SLAVE") == "0":
    os.close(slave); slave = None
proc = subprocess.Popen(CMD, shell=True, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, bufsize=1)
nid = 0
def ask(op):
    global nid
    proc.stdin.write(json.dumps({"id": nid, **op}) + "\n"); proc.stdin.flush()
    nid += 1
    while True:
        line = proc.stdout.readline()
        if not line:
            return {"dead": True}
        a = json.loads(line)
        if a.get("id") == nid - 1:
            return a

pending = b""
REQ_GAPS = []  # (gap since the previous request's end, s) for each request
last_end = [None]
def rtu_len(b):
    if len(b) < 2: return None
    if b[1] == 0x10:
        return 9 + b[6] if len(b) >= 7 else None
    return 8
def read_request(timeout):
    """Bytes of one request (RTU: by its length, else until 15 ms of silence; ASCII: until LF)."""
    global pending
    buf = pending; pending = b""; deadline = time.monotonic() + timeout
    while True:
        if MODE == "rtu" and rtu_len(buf) and len(buf) >= rtu_len(buf):
            n = rtu_len(buf); pending = buf[n:]; return buf[:n]
        if MODE == "ascii" and b"\n" in buf:
            i = buf.index(b"\n") + 1; pending = buf[i:]; return buf[:i]
        left = deadline - time.monotonic() if not buf else 0.015
        r, _, _ = select.select([master], [], [], max(left, 0))
        if not r:
            return buf
        try:
            buf += os.read(master, 512)
        except OSError:  # EIO: nobody has the slave open (between two mbpoll runs)
            if time.monotonic() > deadline:
                return buf
            time.sleep(0.002)

def decode(req):
    if not req:
        return None
    if MODE == "ascii":
        s = req.strip()
        i = s.find(b":")
        return bytes.fromhex(s[i + 1:].decode())[:-1]
    return req[:-2]

seq = 0
def normal_reply(pdu):
    """The drive's reply to the request (address, PDU); a read gets tagged values."""
    global seq
    seq += 1
    addr, fn = pdu[0], pdu[1]
    if fn == 3:
        n = int.from_bytes(pdu[4:6], "big")
        vals = b"".join((0xA000 + 0x10 * seq + i).to_bytes(2, "big") for i in range(n))
        return bytes([addr, 3, 2 * n]) + vals
    if fn == 6:
        return pdu[:6]
    if fn == 0x10:
        return pdu[:6]
    if fn == 8:
        return pdu
    return bytes([addr, fn | 0x80, 1])

def tags_of(answer):
    return answer.get("values")

open_req = {"op": "open", "line": {"kind": "pty", "path": path}, "mode": MODE, "baud": 19200,
            "parity": "N", "data_bits": 8, "stop_bits": 1, "timeout_ms": TMO, "retries": int(os.environ.get("RETRIES", "0"))}
hello = ask({"op": "hello", "protocol": 1, "role": "master"})
print("hello:", hello.get("implementation"), hello.get("version"))
print("open:", ask(open_req))

READ = {"op": "read", "unit": 1, "start": "2520", "count": 2}

def take_request(into):
    """The master's next request: when it came and its bytes go into `into`; its PDU
    (None where it does not decode)."""
    req = read_request(TMO / 1000 + 2)
    into["t"] = time.monotonic()
    pdu = decode(req)
    into["request"] = req.hex(" ")
    return pdu

def run_case(name, fault, op=READ, after=None):
    """fault(pdu) -> list of (delay_s, bytes) to write after the request."""
    result = {}
    def drive():
        pdu = take_request(result)
        if pdu is None:
            return
        t0 = time.monotonic()
        for delay, data in fault(pdu):
            time.sleep(max(0, t0 + delay - time.monotonic()))
            os.write(master, data)
    th = threading.Thread(target=drive); th.start()
    a = ask(op)
    for k in range(int(os.environ.get('NEXT', '1'))):
     # recovery: a normal read, answered normally; stale bytes may arrive here too
     r = {}
     def drive2():
         pdu = take_request(r)
         if after:
             after(r)
         th.join()  # whatever the fault still sends (a stale reply) goes first
         if pdu:
             time.sleep(0.012)
             os.write(master, frame(normal_reply(pdu)))
             r["tag"] = f"{0xA000 + 0x10 * seq:04X}"
     th2 = threading.Thread(target=drive2); th2.start()
     b = ask(READ)
     th2.join()
     ok_next = b.get("values", [None])[0] == r.get("tag")
     print(f"{name:28} -> {summ(a):55} | next: {summ(b)} (own tag {r.get('tag')}) {'OK' if ok_next else 'WRONG'}" + (f" [next request {1000*(r['t']-result['t']):.0f} ms after this one]" if op is not READ and 't' in r and 't' in result else ""))

def summ(a):
    if a.get("result") == "values":
        return "values " + " ".join(a["values"])
    if a.get("result") == "exception":
        return "exception " + a["code"]
    if a.get("result") == "error":
        return f"error {a['kind']}: {a.get('message','')[:40]}"
    if a.get("result") in ("done", "echo"):
        return a["result"]
    if a.get("result") == "raised":
        return f"raised {a.get('type')}: {a.get('message','')[:40]}"
    return json.dumps(a)[:60]

T = TMO / 1000
def f(reply_fn):
    return reply_fn

cases = {
    "normal": lambda p: [(0.012, frame(normal_reply(p)))],
    "exception-02": lambda p: [(0.012, frame(bytes([p[0], p[1] | 0x80, 0x02])))],
    "exception-04": lambda p: [(0.012, frame(bytes([p[0], p[1] | 0x80, 0x04])))],
    "exception-05": lambda p: [(0.012, frame(bytes([p[0], p[1] | 0x80, 0x05])))],
    "exception-07": lambda p: [(0.012, frame(bytes([p[0], p[1] | 0x80, 0x07])))],
    "exception-0B": lambda p: [(0.012, frame(bytes([p[0], p[1] | 0x80, 0x0B])))],
    "exception-51": lambda p: [(0.012, frame(bytes([p[0], p[1] | 0x80, 0x51])))],
    "exception-55": lambda p: [(0.012, frame(bytes([p[0], p[1] | 0x80, 0x55])))],
    "late-inside": lambda p: [(T * 0.6, frame(normal_reply(p)))],
    # the reply after the master's timeout, while its next request waits
    "stale-in-flight": lambda p: [(T + 0.08, frame(normal_reply(p)))],
    "no-reply": lambda p: [],
    "truncated": lambda p: [(0.012, frame(normal_reply(p))[:-2 if MODE == "rtu" else -3])],
    "bad-checksum": lambda p: [(0.012, frame(normal_reply(p), bad=True))],
    "garbage-before": lambda p: [(0.012, b"\xff\x7e\x11" + frame(normal_reply(p)))],
    "lone-00-before": lambda p: [(0.012, b"\x00" + frame(normal_reply(p)))],
    "garbage-after": lambda p: [(0.012, frame(normal_reply(p)) + b"\xff\x7e\x11")],
    "lone-00-after": lambda p: [(0.012, frame(normal_reply(p)) + b"\x00")],
    "exception-no-crc": lambda p: [(0.012, bytes([p[0], p[1] | 0x80, 0x02]) if MODE == "rtu"
                                    else b":" + bytes([p[0], p[1] | 0x80, 0x02]).hex().upper().encode() + b"\r\n")],
    "other-node": lambda p: [(0.012, frame(bytes([p[0] + 1]) + normal_reply(p)[1:]))],
    "split-gap": lambda p: [(0.012, frame(normal_reply(p))[:4]), (0.012 + 0.05, frame(normal_reply(p))[4:])] if False else
        (lambda fr: [(0.012, fr[:4]), (0.062, fr[4:])])(frame(normal_reply(p))),
    "wrong-function": lambda p: [(0.012, frame(bytes([p[0], 0x06, 0x25, 0x02, 0x17, 0x70])))],
    "wrong-function-02": lambda p: [(0.012, frame(bytes([p[0], 0x06, 0x02, 0x02, 0x17, 0x70])))],
    "twice": lambda p: (lambda fr: [(0.012, fr), (0.030, fr)])(frame(normal_reply(p))),
}

def drain():
    """Each case starts on a quiet line: what either side has not read is dropped (the
    tty's queues, never what a library keeps in its own buffers)."""
    global pending
    time.sleep(T + 0.1)
    pending = b""
    for fd in (master, slave) if slave is not None else (master,):
        while select.select([fd], [], [], 0.02)[0]:
            try:
                os.read(fd, 512)
            except OSError:
                break

for name, fault in cases.items():
    if ONLY and not any(o in name for o in ONLY):
        continue
    drain()
    run_case(name, fault)

# stale reply that arrives between requests (in the master's input buffer before its next request)
if not ONLY or "stale-waiting" in ONLY:
    def stale_waiting(p):
        return [(T + 0.03, frame(normal_reply(p)))]
    drain()
    # hold the adapter's next operation until the stale reply is on the line
    result = {}
    def drive():
        req = read_request(T + 2); pdu = decode(req)
        time.sleep(T + 0.03); os.write(master, frame(normal_reply(pdu)))
    th = threading.Thread(target=drive); th.start()
    a = ask(READ); th.join(); time.sleep(0.1)
    r = {}
    def drive2():
        req = read_request(T + 2); pdu = decode(req)
        if pdu:
            time.sleep(0.012); os.write(master, frame(normal_reply(pdu))); r["tag"] = f"{0xA000 + 0x10 * seq:04X}"
    th = threading.Thread(target=drive2); th.start()
    b = ask(READ); th.join()
    ok = b.get("values", [None])[0] == r.get("tag")
    print(f"{'stale-waiting':28} -> {summ(a):55} | next: {summ(b)} (own tag {r.get('tag')}) {'OK' if ok else 'WRONG'}")

# broadcast: the write to unit 0, never answered
if not ONLY or "broadcast" in ONLY:
    if "broadcast" in hello.get("supports", []):
        drain()
        run_case("broadcast-write", lambda p: [], op={"op": "write-single", "unit": 0, "register": "2502", "value": "1770"})
        drain()
        run_case("broadcast-answered", lambda p: [(0.012, frame(p[:6]))], op={"op": "write-single", "unit": 0, "register": "2502", "value": "1770"})

proc.stdin.close(); proc.wait(timeout=10)
