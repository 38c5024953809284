//! No heap allocation on any decode, emit, conversion or deframing path: proven with a
//! counting global allocator (counted per thread, so the test harness does not interfere).

use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;

use conformance::codec::{
    ascii_to_rtu, crc16, decode_ascii, decode_ascii_unchecked, decode_rtu, decode_rtu_unchecked,
    lrc, rtu_to_ascii, AsciiDeframer, Direction, Event, Message, Pdu, Registers, RtuDeframer,
    RtuFraming, MAX_ASCII_FRAME, MAX_RTU_FRAME,
};

struct Counting;

thread_local! {
    static ALLOCATIONS: Cell<usize> = const { Cell::new(0) };
}

unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        let _ = ALLOCATIONS.try_with(|c| c.set(c.get() + 1));
        unsafe { System.alloc(layout) }
    }
    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        unsafe { System.dealloc(ptr, layout) }
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn allocations_in(f: impl FnOnce()) -> usize {
    let before = ALLOCATIONS.with(Cell::get);
    f();
    ALLOCATIONS.with(Cell::get) - before
}

#[test]
fn counting_allocator_counts() {
    // The instrument works: a Vec allocates.
    assert!(allocations_in(|| drop(std::hint::black_box(vec![1u8; 10]))) >= 1);
}

#[test]
fn decode_emit_convert_and_deframe_do_not_allocate() {
    let regs = [0x17u8, 0x70, 0x00, 0x01];
    let messages = [
        (
            Direction::Request,
            Pdu::ReadRequest {
                start: 0x2520,
                count: 2,
            },
        ),
        (
            Direction::Response,
            Pdu::ReadResponse {
                values: Registers::new(&regs).unwrap(),
            },
        ),
        (
            Direction::Request,
            Pdu::WriteSingle {
                register: 0x2502,
                value: 0x1770,
            },
        ),
        (
            Direction::Request,
            Pdu::LoopBack {
                test_code: 0,
                data: &[0xA5, 0x37],
            },
        ),
        (
            Direction::Request,
            Pdu::WriteMultipleRequest {
                start: 0x2502,
                values: Registers::new(&regs).unwrap(),
            },
        ),
        (
            Direction::Response,
            Pdu::WriteMultipleResponse {
                start: 0x2502,
                count: 2,
            },
        ),
        (
            Direction::Response,
            Pdu::Exception {
                function: 3,
                code: 2,
            },
        ),
        (
            Direction::Request,
            Pdu::Other {
                function: 0x41,
                data: &[1, 2, 3],
            },
        ),
    ];
    // Frames are prepared before counting.
    let frames: Vec<(Direction, Message<'_>, Vec<u8>, Vec<u8>)> = messages
        .iter()
        .map(|(d, p)| {
            let m = Message {
                address: 1,
                pdu: *p,
            };
            (*d, m, m.to_rtu_vec().unwrap(), m.to_ascii_vec().unwrap())
        })
        .collect();
    let mut rtu_deframer = RtuDeframer::new(Direction::Response, RtuFraming::ByLength);
    let mut ascii_deframer = AsciiDeframer::default();
    let mut big = vec![0u8; 64 * 1024];
    big[0] = 1;

    let n = allocations_in(|| {
        for (dir, m, rtu, ascii) in &frames {
            let mut out = [0u8; MAX_ASCII_FRAME];
            let mut scratch = [0u8; MAX_RTU_FRAME];
            assert_eq!(decode_rtu(rtu, *dir).unwrap(), *m);
            assert!(decode_rtu_unchecked(rtu, *dir).unwrap().checksum.is_valid());
            assert_eq!(decode_ascii(ascii, *dir, &mut scratch).unwrap(), *m);
            let mut scratch = [0u8; MAX_RTU_FRAME];
            assert!(decode_ascii_unchecked(ascii, *dir, &mut scratch).is_ok());
            m.emit_rtu(&mut out).unwrap();
            m.emit_ascii(&mut out).unwrap();
            rtu_to_ascii(rtu, &mut out).unwrap();
            ascii_to_rtu(ascii, &mut out).unwrap();
            let mut frames_seen = 0;
            rtu_deframer.push(rtu, |e| {
                frames_seen += matches!(e, Event::Frame(_)) as usize
            });
            rtu_deframer.push(&[0xFF, 0x00], |_| {});
            rtu_deframer.flush(|_| {});
            ascii_deframer.push(ascii, |e| {
                frames_seen += matches!(e, Event::Frame(_)) as usize
            });
            ascii_deframer.push(b"junk", |_| {});
            ascii_deframer.flush(|_| {});
            assert!(frames_seen >= 1);
            // A bad checksum is an error value, not an allocation.
            let mut bad = [0u8; MAX_RTU_FRAME];
            bad[..rtu.len()].copy_from_slice(rtu);
            bad[rtu.len() - 1] ^= 0xFF;
            assert!(decode_rtu(&bad[..rtu.len()], *dir).is_err());
        }
        std::hint::black_box(crc16(&big));
        std::hint::black_box(lrc(&big));
    });
    assert_eq!(n, 0, "{n} heap allocations on codec paths");
}
