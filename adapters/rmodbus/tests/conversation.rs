//! Runs the built `rmodbus-adapter` binary and talks to it as the gate does: one JSON
//! request per line on its standard input, one answer per line on its standard output.
//!
//! Where rmodbus behaves differently from a correct Modbus codec, these tests assert what
//! rmodbus actually does, marked "rmodbus finding", so that a change in rmodbus shows up
//! here instead of being hidden.

use std::io::{BufRead, BufReader, Write};
use std::process::{Child, ChildStdin, Command, Stdio};
use std::sync::mpsc::{channel, Receiver};
use std::thread;
use std::time::Duration;

use serde_json::{json, Value};

/// How long one answer may take before the test fails instead of hanging.
const ANSWER_TIMEOUT: Duration = Duration::from_secs(20);

struct Adapter {
    child: Child,
    stdin: Option<ChildStdin>,
    lines: Receiver<String>,
    next_id: u64,
}

impl Adapter {
    fn start() -> Self {
        let mut child = Command::new(env!("CARGO_BIN_EXE_rmodbus-adapter"))
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .stderr(Stdio::null())
            .spawn()
            .expect("start rmodbus-adapter");
        let stdin = child.stdin.take();
        let stdout = child.stdout.take().expect("stdout");
        let (tx, rx) = channel();
        thread::spawn(move || {
            for line in BufReader::new(stdout).lines() {
                let Ok(line) = line else { return };
                if tx.send(line).is_err() {
                    return;
                }
            }
        });
        Adapter {
            child,
            stdin,
            lines: rx,
            next_id: 0,
        }
    }

    /// Sends one raw line and returns the one answer line, parsed.
    fn send_line(&mut self, line: &str) -> Value {
        let stdin = self.stdin.as_mut().expect("stdin open");
        stdin.write_all(line.as_bytes()).expect("write");
        stdin.write_all(b"\n").expect("write");
        stdin.flush().expect("flush");
        let answer = self
            .lines
            .recv_timeout(ANSWER_TIMEOUT)
            .unwrap_or_else(|e| panic!("no answer to {line:?}: {e}"));
        serde_json::from_str(&answer)
            .unwrap_or_else(|e| panic!("answer {answer:?} is not JSON: {e}"))
    }

    /// Sends `request` with the next id; checks the answer repeats it.
    fn call(&mut self, mut request: Value) -> Value {
        let id = self.next_id;
        self.next_id += 1;
        request["id"] = json!(id);
        let answer = self.send_line(&request.to_string());
        assert_eq!(answer["id"], json!(id), "answer {answer} to {request}");
        answer
    }

    fn decode(&mut self, mode: &str, direction: &str, frame: &str) -> Value {
        self.call(json!({"op": "decode", "mode": mode, "direction": direction, "frame": frame}))
    }

    fn encode(&mut self, mode: &str, direction: &str, message: &Value) -> Value {
        self.call(json!({"op": "encode", "mode": mode, "direction": direction, "message": message}))
    }

    /// Decodes a frame that must be accepted; returns its message.
    fn accepted(&mut self, mode: &str, direction: &str, frame: &str) -> Value {
        let a = self.decode(mode, direction, frame);
        assert_eq!(a["ok"], json!(true), "{a}");
        assert_eq!(a["accepted"], json!(true), "{frame}: {a}");
        a["message"].clone()
    }

    /// Decodes a frame that must be refused; returns the reason.
    fn refused(&mut self, mode: &str, direction: &str, frame: &str) -> String {
        let a = self.decode(mode, direction, frame);
        assert_eq!(a["ok"], json!(true), "{a}");
        assert_eq!(a["accepted"], json!(false), "{frame}: {a}");
        a["reason"].as_str().expect("reason").to_string()
    }

    /// Encodes a message that must be encodable; returns the frame.
    fn encoded(&mut self, mode: &str, direction: &str, message: &Value) -> String {
        let a = self.encode(mode, direction, message);
        assert_eq!(a["ok"], json!(true), "{message}: {a}");
        a["frame"].as_str().expect("frame").to_string()
    }
}

impl Drop for Adapter {
    fn drop(&mut self) {
        // End of input: the adapter exits by itself.
        drop(self.stdin.take());
        for _ in 0..200 {
            if let Ok(Some(_)) = self.child.try_wait() {
                return;
            }
            thread::sleep(Duration::from_millis(10));
        }
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// The hex codes of an ASCII frame's characters, as the protocol carries them.
fn ascii(text: &str) -> String {
    text.bytes()
        .map(|b| format!("{b:02X}"))
        .collect::<Vec<_>>()
        .join(" ")
}

fn read_request(start: &str, count: u64) -> Value {
    json!({"address": "01", "function": "03", "kind": "read-request",
           "fields": {"start": start, "count": count}})
}

#[test]
fn conversation() {
    let mut a = Adapter::start();

    let hello = a.call(json!({"op": "hello", "protocol": 1}));
    assert_eq!(hello["ok"], json!(true), "{hello}");
    assert_eq!(hello["protocol"], json!(1));
    assert_eq!(hello["adapter"], json!("rmodbus-adapter"));
    assert_eq!(hello["implementation"], json!("rmodbus"));
    assert!(
        hello["version"].as_str().unwrap().starts_with("0.13"),
        "{hello}"
    );
    assert_eq!(hello["supports"], json!(["decode", "encode", "crc", "lrc"]));

    // RTU request (F510 03H example).
    let m = a.accepted("rtu", "request", "01 03 01 23 00 01 74 3C");
    assert_eq!(m, read_request("0123", 1));

    // RTU response, corrected CRC.
    let m = a.accepted("rtu", "response", "01 03 02 17 70 B6 50");
    assert_eq!(
        m,
        json!({"address": "01", "function": "03", "kind": "read-response",
               "fields": {"byte_count": 2, "values": ["1770"]}})
    );

    // The same response with the CRC the F510 manual prints: refused.
    let reason = a.refused("rtu", "response", "01 03 02 17 70 AF 82");
    assert!(reason.starts_with("CRC error"), "{reason}");

    // Bad CRC on a request: refused.
    let reason = a.refused("rtu", "request", "01 03 01 23 00 01 74 3D");
    assert!(reason.starts_with("CRC error"), "{reason}");

    let m = a.accepted("rtu", "request", "01 06 01 02 17 70 27 E2");
    assert_eq!(
        m,
        json!({"address": "01", "function": "06", "kind": "write-single",
               "fields": {"register": "0102", "value": "1770"}})
    );

    let m = a.accepted("rtu", "request", "01 10 01 01 00 02 04 00 01 17 70 60 27");
    assert_eq!(
        m,
        json!({"address": "01", "function": "10", "kind": "write-multiple-request",
               "fields": {"start": "0101", "count": 2, "byte_count": 4,
                          "values": ["0001", "1770"]}})
    );

    // ASCII request, and the same with a wrong LRC.
    let m = a.accepted("ascii", "request", &ascii(":010301230001D7\r\n"));
    assert_eq!(m, read_request("0123", 1));
    let reason = a.refused("ascii", "request", &ascii(":010301230001D8\r\n"));
    assert!(reason.starts_with("LRC error"), "{reason}");

    // Encoding, checked against the manuals' frames.
    let frame = a.encoded("rtu", "request", &read_request("0123", 1));
    assert_eq!(frame, "01 03 01 23 00 01 74 3C");
    let frame = a.encoded("ascii", "request", &read_request("0123", 1));
    assert_eq!(frame, ascii(":010301230001D7\r\n"));
    let write_single = json!({"address": "01", "function": "06", "kind": "write-single",
                              "fields": {"register": "0102", "value": "1770"}});
    let frame = a.encoded("ascii", "request", &write_single);
    assert_eq!(frame, "3A 30 31 30 36 30 31 30 32 31 37 37 30 36 46 0D 0A");

    // crc and lrc.
    let c = a.call(json!({"op": "crc", "data": "01 03 01 23 00 01"}));
    assert_eq!(c["ok"], json!(true), "{c}");
    assert_eq!(c["crc"], json!("3C74"));
    let l = a.call(json!({"op": "lrc", "data": "01 03 01 00 0A"}));
    assert_eq!(l["ok"], json!(true), "{l}");
    assert_eq!(l["lrc"], json!("F1"));

    // An unknown operation.
    let u = a.call(json!({"op": "frobnicate"}));
    assert_eq!(u["ok"], json!(false), "{u}");
    assert_eq!(u["error"], json!("unsupported"));

    // A line that is not JSON: an error with id null, and the adapter carries on.
    let bad = a.send_line("this is not JSON");
    assert_eq!(bad["ok"], json!(false), "{bad}");
    assert_eq!(bad["id"], Value::Null);
    assert!(bad["error"].as_str().unwrap().starts_with("not JSON"));
    let c = a.call(json!({"op": "crc", "data": "01 03 01 23 00 01"}));
    assert_eq!(c["crc"], json!("3C74"), "{c}");

    // A request for a protocol the adapter does not speak.
    let h = a.call(json!({"op": "hello", "protocol": 2}));
    assert_eq!(h["ok"], json!(false), "{h}");

    // Missing or malformed fields are errors, not crashes.
    let e = a.call(json!({"op": "decode", "mode": "rtu", "direction": "request"}));
    assert_eq!(e["ok"], json!(false), "{e}");
    let e = a.call(json!({"op": "decode", "mode": "rtu", "direction": "request", "frame": "0G"}));
    assert_eq!(e["ok"], json!(false), "{e}");
    let e = a.call(
        json!({"op": "encode", "mode": "rtu", "direction": "request",
                          "message": {"address": "01", "function": "03", "kind": "read-request",
                                      "fields": {"start": "0123"}}}),
    );
    assert_eq!(e["ok"], json!(false), "{e}");

    // 08H: rmodbus has no loop-back, in either direction.
    let loop_back = json!({"address": "01", "function": "08", "kind": "loop-back",
                           "fields": {"test_code": "0000", "data": "A5 37"}});
    let e = a.encode("rtu", "request", &loop_back);
    assert_eq!(e["error"], json!("unsupported"), "{e}");
    let e = a.decode("rtu", "request", "01 08 00 00 A5 37 DA 8D");
    assert_eq!(e["error"], json!("unsupported"), "{e}");
}

#[test]
fn encode_round_trips() {
    let mut a = Adapter::start();
    let requests = [
        read_request("0123", 1),
        read_request("2520", 16),
        json!({"address": "01", "function": "06", "kind": "write-single",
               "fields": {"register": "0102", "value": "1770"}}),
        json!({"address": "11", "function": "10", "kind": "write-multiple-request",
               "fields": {"start": "0101", "count": 2, "byte_count": 4,
                          "values": ["0001", "1770"]}}),
    ];
    let responses = [
        json!({"address": "01", "function": "03", "kind": "read-response",
               "fields": {"byte_count": 4, "values": ["1770", "0001"]}}),
        json!({"address": "01", "function": "06", "kind": "write-single",
               "fields": {"register": "0102", "value": "1770"}}),
        json!({"address": "01", "function": "10", "kind": "write-multiple-response",
               "fields": {"start": "0101", "count": 2}}),
        json!({"address": "01", "function": "83", "kind": "exception",
               "fields": {"exception_function": "03", "code": "02"}}),
        json!({"address": "01", "function": "90", "kind": "exception",
               "fields": {"exception_function": "10", "code": "0A"}}),
    ];
    for mode in ["rtu", "ascii"] {
        for (direction, messages) in [("request", &requests[..]), ("response", &responses[..])] {
            for message in messages {
                let frame = a.encoded(mode, direction, message);
                let a_decode = a.decode(mode, direction, &frame);
                assert_eq!(
                    a_decode["accepted"],
                    json!(true),
                    "{mode} {frame}: {a_decode}"
                );
                if message["kind"] == json!("exception") && message["fields"]["code"] == json!("0A")
                {
                    // rmodbus finding: its client maps exception code 0A to
                    // ErrorKind::UnknownError (ErrorKind::from_modbus_error has 0x10 where
                    // 0x0A belongs); the adapter reads the code from the checked bytes and
                    // says so in a note.
                    let note = a_decode["note"].as_str().unwrap_or_default();
                    assert!(note.contains("UnknownError"), "{a_decode}");
                }
                assert_eq!(&a_decode["message"], message, "{mode} {direction} {frame}");
            }
        }
    }

    // Known frames.
    let frame = a.encoded("rtu", "response", &responses[0]);
    assert_eq!(frame, "01 03 04 17 70 00 01 3F 9C");
    let frame = a.encoded("rtu", "response", &responses[3]);
    assert_eq!(frame, "01 83 02 C0 F1");
    let frame = a.encoded("rtu", "request", &requests[1]);
    assert_eq!(frame, "01 03 25 20 00 10 4E C0");

    // An exception to a function rmodbus does not implement (08H) is still encoded: its
    // server answers any unknown function, and the adapter sets the code.
    let e = json!({"address": "01", "function": "88", "kind": "exception",
                   "fields": {"exception_function": "08", "code": "03"}});
    let frame = a.encoded("rtu", "response", &e);
    assert_eq!(frame, "01 88 03 06 01");

    // Exception codes outside rmodbus's ModbusErrorCode (the TECO 51H..55H ones) cannot be
    // encoded by it.
    let e = json!({"address": "01", "function": "83", "kind": "exception",
                   "fields": {"exception_function": "03", "code": "51"}});
    let answer = a.encode("rtu", "response", &e);
    assert_eq!(answer["error"], json!("unsupported"), "{answer}");

    // Inconsistent count/byte count cannot be expressed through rmodbus's generators.
    let m = json!({"address": "01", "function": "10", "kind": "write-multiple-request",
                   "fields": {"start": "0101", "count": 3, "byte_count": 4,
                              "values": ["0001", "1770"]}});
    let answer = a.encode("rtu", "request", &m);
    assert_eq!(answer["error"], json!("unsupported"), "{answer}");
}

#[test]
fn rmodbus_findings() {
    let mut a = Adapter::start();

    // --- requests (rmodbus's server, ModbusFrame::parse)

    // rmodbus finding: bytes after a valid CRC are ignored; the frame is accepted.
    let m = a.accepted("rtu", "request", "01 03 01 23 00 01 74 3C FF");
    assert_eq!(m, read_request("0123", 1));

    // rmodbus finding: a 10H request's byte count is not checked against its register
    // count (count 2, byte count 2: accepted; count 1, byte count 4: accepted).
    let d = a.decode("rtu", "request", "01 10 01 01 00 02 02 00 01 76 C5");
    assert_eq!(d["accepted"], json!(true), "{d}");
    assert_eq!(d["message"]["fields"]["count"], json!(2));
    assert_eq!(d["message"]["fields"]["byte_count"], json!(2));
    let d = a.decode("rtu", "request", "01 10 01 01 00 01 04 00 01 17 70 60 14");
    assert_eq!(d["accepted"], json!(true), "{d}");
    assert_eq!(d["message"]["fields"]["values"], json!(["0001", "1770"]));

    // rmodbus finding: a 10H request with a byte count of 249 or more makes
    // ModbusFrame::parse compute `7 + bytes` in u8: that overflows. A debug build panics
    // ("attempt to add with overflow"); a release build wraps to a bogus length and reports
    // a CRC error. The adapter survives the panic and answers an error.
    let d = a.decode("rtu", "request", "01 10 01 01 00 01 FF 00 00");
    if cfg!(debug_assertions) {
        assert_eq!(d["raised"], json!(true), "{d}");
        let e = d["reason"].as_str().unwrap();
        assert!(e.starts_with("rmodbus panicked"), "{d}");
        assert!(e.contains("overflow"), "{d}");
    } else {
        assert_eq!(d["accepted"], json!(false), "{d}");
    }

    // rmodbus finding: a read of 0 registers is accepted (the spec's range is 1..125; the
    // server only refuses counts over 125, with exception 03).
    let m = a.accepted("rtu", "request", "01 03 01 23 00 00 B5 FC");
    assert_eq!(m, read_request("0123", 0));
    let reason = a.refused("rtu", "request", "01 03 01 23 00 7E 35 DC");
    assert!(reason.contains("exception 03"), "{reason}");

    // rmodbus finding: for a function it does not implement (08H here), ModbusFrame::parse
    // checks no CRC: a corrupted frame is taken as addressed to the slave and answered with
    // exception 01, where a correct slave would discard it silently.
    let d = a.decode("rtu", "request", "01 08 00 00 12 34 ED 00");
    assert_eq!(d["error"], json!("unsupported"), "{d}");
    assert!(
        d["detail"]
            .as_str()
            .unwrap()
            .contains("would answer exception 01"),
        "{d}"
    );

    // Broadcast: rmodbus ignores a read sent to address 0 (correct: no reply to a broadcast
    // read), without checking it.
    let reason = a.refused("rtu", "request", "00 03 01 23 00 01 75 ED");
    assert!(reason.contains("broadcast"), "{reason}");

    // --- responses (rmodbus's client, ModbusRequest::parse_*)

    // rmodbus finding: a read response with byte count 0 makes ModbusRequest::parse_u16
    // panic (`data.len() - 1` on empty data). rmodbus's own server emits exactly this frame
    // for a read of 0 registers, which it accepts (above).
    let d = a.decode("rtu", "response", "01 03 00 20 F0");
    assert_eq!(
        (&d["accepted"], &d["raised"]),
        (&json!(false), &json!(true)),
        "{d}"
    );
    assert_panicked(&d);
    let empty = json!({"address": "01", "function": "03", "kind": "read-response",
                       "fields": {"byte_count": 0, "values": []}});
    assert_eq!(a.encoded("rtu", "response", &empty), "01 03 00 20 F0");
    // ... and the adapter is still there.
    let m = a.accepted("rtu", "response", "01 03 02 17 70 B6 50");
    assert_eq!(m["fields"]["values"], json!(["1770"]));

    // rmodbus finding: the byte count of a read response is checked only as
    // `byte_count * 2 >= data bytes`: a byte count of 4 over 2 data bytes, a byte count of 1
    // over 1 byte, and a byte count of 2 over 3 bytes are all accepted.
    let d = a.decode("rtu", "response", "01 03 04 17 70 56 51");
    assert_eq!(d["accepted"], json!(true), "{d}");
    assert_eq!(d["message"]["fields"]["values"], json!(["1770"]));
    let d = a.decode("rtu", "response", "01 03 01 17 B0 46");
    assert_eq!(d["accepted"], json!(true), "{d}");
    assert_eq!(d["message"]["fields"]["values"], json!([]));
    let d = a.decode("rtu", "response", "01 03 02 17 70 AA 51 C9");
    assert_eq!(d["accepted"], json!(true), "{d}");

    // rmodbus finding: the length of write responses is not checked (06H with 2 or 6 data
    // bytes instead of 4, 10H with 3).
    for frame in [
        "01 06 01 02 61 88",
        "01 06 01 02 17 70 00 00 9B B9",
        "01 10 01 01 00 4D 50",
    ] {
        let d = a.decode("rtu", "response", frame);
        assert_eq!(d["accepted"], json!(true), "{frame}: {d}");
        assert!(
            d["note"].as_str().unwrap().contains("does not check"),
            "{d}"
        );
    }

    // rmodbus finding: the length of exception responses is not checked either.
    let d = a.decode("rtu", "response", "01 83 02 00 F1 50");
    assert_eq!(d["accepted"], json!(true), "{d}");
    assert_eq!(d["message"]["fields"]["code"], json!("02"));

    // rmodbus finding: exception code 0A comes out as ErrorKind::UnknownError
    // (ErrorKind::from_modbus_error maps 0x10, not 0x0A, to GatewayTargetFailed); codes
    // outside 01..0A (TECO's 51H..55H) also come out as UnknownError, code lost.
    for (frame, code) in [("01 83 0A C1 37", "0A"), ("01 83 51 80 CC", "51")] {
        let d = a.decode("rtu", "response", frame);
        assert_eq!(d["accepted"], json!(true), "{d}");
        assert_eq!(d["message"]["fields"]["code"], json!(code));
        assert!(d["note"].as_str().unwrap().contains("UnknownError"), "{d}");
    }

    // --- ASCII (parse_ascii_frame)

    // rmodbus finding: parse_ascii_frame indexes data[0] unchecked: an empty frame panics.
    let d = a.decode("ascii", "request", "");
    assert_eq!(d["raised"], json!(true), "{d}");
    assert_panicked(&d);

    // rmodbus finding: the ':' start and the CR LF end are optional, and whatever follows
    // the CR is ignored.
    for text in [
        "010301230001D7\r\n",
        ":010301230001D7",
        ":010301230001D7\r",
        ":010301230001D7\r\nXYZ",
    ] {
        let m = a.accepted("ascii", "request", &ascii(text));
        assert_eq!(m, read_request("0123", 1), "{text:?}");
    }

    // Lower-case hex is refused by parse_ascii_frame (Modbus ASCII specifies upper case;
    // this suite's codec accepts lower case), as is a ':' inside a frame.
    a.refused("ascii", "request", &ascii(":010301230001d7\r\n"));
    a.refused("ascii", "request", &ascii(":01030123:0001D7\r\n"));

    // --- encoding (rmodbus's client generators)

    // rmodbus finding: generate_set_holdings_bulk accepts up to 125 values, over the 123
    // a 10H request may carry, while rmodbus's own server refuses more than 123 (so the
    // matching response cannot be made).
    let values: Vec<String> = (0..124).map(|i| format!("{i:04X}")).collect();
    let big = json!({"address": "01", "function": "10", "kind": "write-multiple-request",
                     "fields": {"start": "0000", "count": 124, "byte_count": 248,
                                "values": values}});
    let frame = a.encoded("rtu", "request", &big);
    assert!(frame.starts_with("01 10 00 00 00 7C F8 "), "{frame}");
    let big_response = json!({"address": "01", "function": "10",
                              "kind": "write-multiple-response",
                              "fields": {"start": "0000", "count": 124}});
    let answer = a.encode("rtu", "response", &big_response);
    assert_eq!(answer["error"], json!("unsupported"), "{answer}");

    // rmodbus finding: generate_get_holdings does not check the count (0 and 2000 encode).
    assert_eq!(
        a.encoded("rtu", "request", &read_request("0123", 0)),
        "01 03 01 23 00 00 B5 FC"
    );
    assert_eq!(
        a.encoded("rtu", "request", &read_request("0123", 2000)),
        "01 03 01 23 07 D0 B6 50"
    );

    // rmodbus checksums at most 255 bytes.
    let long = vec!["00"; 256].join(" ");
    let c = a.call(json!({"op": "crc", "data": long}));
    assert_eq!(c["error"], json!("unsupported"), "{c}");
    let c = a.call(json!({"op": "crc", "data": ""}));
    assert_eq!(c["crc"], json!("FFFF"), "{c}");
}

/// The adapter answered that rmodbus panicked on the frame (and caught it).
fn assert_panicked(d: &Value) {
    let reason = d["reason"].as_str().unwrap();
    assert!(reason.starts_with("rmodbus panicked"), "{d}");
}
