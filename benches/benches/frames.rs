//! Frame paths: checked decode, emit and ASCII<->RTU conversion for 03H, 06H, 08H, 10H and
//! exceptions, both directions, RTU and ASCII; and the peers rmodbus and modbus-core on the
//! same 03H request and response, in the same run.

use conformance::codec::{
    ascii_to_rtu, decode_ascii, decode_rtu, rtu_to_ascii, Direction, Message, Pdu, Registers,
    MAX_ASCII_FRAME, MAX_RTU_FRAME,
};
use criterion::{black_box, criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};

const TEN_REGISTERS: [u8; 20] = [
    0x17, 0x70, 0x00, 0x01, 0x00, 0x02, 0x00, 0x03, 0x00, 0x04, 0x00, 0x05, 0x00, 0x06, 0x00, 0x07,
    0x00, 0x08, 0x00, 0x09,
];

fn messages() -> Vec<(&'static str, Direction, Message<'static>)> {
    let regs = Registers::new(&TEN_REGISTERS).unwrap();
    let one = Registers::new(&TEN_REGISTERS[..2]).unwrap();
    let m = |pdu| Message { address: 1, pdu };
    vec![
        (
            "03-request",
            Direction::Request,
            m(Pdu::ReadRequest {
                start: 0x2520,
                count: 10,
            }),
        ),
        (
            "03-response-1",
            Direction::Response,
            m(Pdu::ReadResponse { values: one }),
        ),
        (
            "03-response-10",
            Direction::Response,
            m(Pdu::ReadResponse { values: regs }),
        ),
        (
            "06-request",
            Direction::Request,
            m(Pdu::WriteSingle {
                register: 0x2502,
                value: 0x1770,
            }),
        ),
        (
            "06-response",
            Direction::Response,
            m(Pdu::WriteSingle {
                register: 0x2502,
                value: 0x1770,
            }),
        ),
        (
            "08-request",
            Direction::Request,
            m(Pdu::LoopBack {
                test_code: 0,
                data: &[0xA5, 0x37],
            }),
        ),
        (
            "08-response",
            Direction::Response,
            m(Pdu::LoopBack {
                test_code: 0,
                data: &[0xA5, 0x37],
            }),
        ),
        (
            "10-request",
            Direction::Request,
            m(Pdu::WriteMultipleRequest {
                start: 0x2502,
                values: regs,
            }),
        ),
        (
            "10-response",
            Direction::Response,
            m(Pdu::WriteMultipleResponse {
                start: 0x2502,
                count: 10,
            }),
        ),
        (
            "exception",
            Direction::Response,
            m(Pdu::Exception {
                function: 3,
                code: 2,
            }),
        ),
    ]
}

fn ours(c: &mut Criterion) {
    for (name, dir, msg) in messages() {
        let rtu = msg.to_rtu_vec().unwrap();
        let ascii = msg.to_ascii_vec().unwrap();
        let mut group = c.benchmark_group(format!("frame/{name}"));
        group.throughput(Throughput::Elements(1));
        group.bench_function("rtu-decode", |b| {
            b.iter(|| decode_rtu(black_box(&rtu), dir).unwrap())
        });
        group.bench_function("ascii-decode", |b| {
            b.iter(|| {
                let mut s = [0u8; MAX_RTU_FRAME];
                decode_ascii(black_box(&ascii), dir, &mut s)
                    .map(|m| m.address)
                    .unwrap()
            })
        });
        group.bench_function("rtu-emit", |b| {
            let mut out = [0u8; MAX_RTU_FRAME];
            b.iter(|| black_box(&msg).emit_rtu(&mut out).unwrap())
        });
        group.bench_function("ascii-emit", |b| {
            let mut out = [0u8; MAX_ASCII_FRAME];
            b.iter(|| black_box(&msg).emit_ascii(&mut out).unwrap())
        });
        group.bench_function("rtu-to-ascii", |b| {
            let mut out = [0u8; MAX_ASCII_FRAME];
            b.iter(|| rtu_to_ascii(black_box(&rtu), &mut out).unwrap())
        });
        group.bench_function("ascii-to-rtu", |b| {
            let mut out = [0u8; MAX_RTU_FRAME];
            b.iter(|| ascii_to_rtu(black_box(&ascii), &mut out).unwrap())
        });
        group.finish();
    }
}

/// Checked RTU decode of the F510 manual's 8-byte 03H request and a 7-byte response to it:
/// ours against rmodbus and modbus-core; and our ASCII decode of the same two messages.
fn peers(c: &mut Criterion) {
    let request = [0x01u8, 0x03, 0x01, 0x23, 0x00, 0x01, 0x74, 0x3C];
    let response = [0x01u8, 0x03, 0x02, 0x17, 0x70, 0xB6, 0x50];

    // The same two messages as ASCII frames, for the ASCII/RTU ratio of our decode.
    let request_ascii = b":010301230001D7\r\n";
    let response_ascii = b":010302177073\r\n";
    let mut s = [0u8; MAX_RTU_FRAME];
    assert_eq!(
        decode_ascii(request_ascii, Direction::Request, &mut s).unwrap(),
        decode_rtu(&request, Direction::Request).unwrap()
    );
    let mut s = [0u8; MAX_RTU_FRAME];
    assert_eq!(
        decode_ascii(response_ascii, Direction::Response, &mut s).unwrap(),
        decode_rtu(&response, Direction::Response).unwrap()
    );

    let mut group = c.benchmark_group("peers/03-request-8B");
    group.throughput(Throughput::Bytes(request.len() as u64));
    group.bench_function(BenchmarkId::from_parameter("ours"), |b| {
        b.iter(|| {
            match decode_rtu(black_box(&request[..]), Direction::Request)
                .unwrap()
                .pdu
            {
                Pdu::ReadRequest { start, count } => (start, count),
                _ => unreachable!(),
            }
        })
    });
    group.bench_function(BenchmarkId::from_parameter("ours-ascii"), |b| {
        // The caller's scratch buffer is set up once, outside the loop, as a deframer's is.
        let mut s = [0u8; MAX_RTU_FRAME];
        b.iter(|| {
            match decode_ascii(black_box(request_ascii), Direction::Request, &mut s)
                .unwrap()
                .pdu
            {
                Pdu::ReadRequest { start, count } => (start, count),
                _ => unreachable!(),
            }
        })
    });
    group.bench_function(BenchmarkId::from_parameter("rmodbus"), |b| {
        // rmodbus's server-side parse (ModbusFrame::parse) checks the CRC and reads the
        // register and count; its response buffer is allocated once, outside the loop.
        let mut response_buf: Vec<u8> = Vec::with_capacity(256);
        b.iter(|| {
            let mut frame = rmodbus::server::ModbusFrame::new(
                1,
                black_box(&request[..]),
                rmodbus::ModbusProto::Rtu,
                &mut response_buf,
            );
            frame.parse().unwrap();
            (frame.reg, frame.count)
        })
    });
    group.bench_function(BenchmarkId::from_parameter("modbus-core"), |b| {
        b.iter(|| {
            modbus_core::rtu::server::decode_request(black_box(&request[..]))
                .unwrap()
                .unwrap()
                .hdr
                .slave
        })
    });
    group.finish();

    let mut group = c.benchmark_group("peers/03-response-7B");
    group.throughput(Throughput::Bytes(response.len() as u64));
    group.bench_function(BenchmarkId::from_parameter("ours"), |b| {
        b.iter(|| {
            match decode_rtu(black_box(&response[..]), Direction::Response)
                .unwrap()
                .pdu
            {
                Pdu::ReadResponse { values } => values.get(0),
                _ => unreachable!(),
            }
        })
    });
    group.bench_function(BenchmarkId::from_parameter("ours-ascii"), |b| {
        // The caller's scratch buffer is set up once, outside the loop, as a deframer's is.
        let mut s = [0u8; MAX_RTU_FRAME];
        b.iter(|| {
            match decode_ascii(black_box(response_ascii), Direction::Response, &mut s)
                .unwrap()
                .pdu
            {
                Pdu::ReadResponse { values } => values.get(0),
                _ => unreachable!(),
            }
        })
    });
    group.bench_function(BenchmarkId::from_parameter("rmodbus"), |b| {
        let mut req = rmodbus::client::ModbusRequest::new(1, rmodbus::ModbusProto::Rtu);
        let mut out: Vec<u8> = Vec::new();
        req.generate_get_holdings(0x0123, 1, &mut out).unwrap();
        let mut values: Vec<u16> = Vec::with_capacity(8);
        b.iter(|| {
            values.clear();
            req.parse_u16(black_box(&response[..]), &mut values)
                .unwrap();
            values[0]
        })
    });
    group.bench_function(BenchmarkId::from_parameter("modbus-core"), |b| {
        b.iter(|| {
            modbus_core::rtu::client::decode_response(black_box(&response[..]))
                .unwrap()
                .unwrap()
                .hdr
                .slave
        })
    });
    group.finish();
}

criterion_group!(benches, ours, peers);
criterion_main!(benches);
