//! Frames and bytes as reports show them: decoded, explained where they hold no valid
//! reply, hex in RTU and characters in ASCII.

use crate::codec::ascii::AsciiFrame;
use crate::codec::hex::Hex;
use crate::codec::pdu::Direction;
use crate::codec::rtu::RtuFrame;
use crate::codec::{self, Mode};

/// Decodes a reply frame for display.
pub fn describe_reply(mode: Mode, frame: &[u8]) -> String {
    let mut scratch = [0u8; codec::MAX_RTU_FRAME];
    match codec::decode_unchecked(mode, frame, Direction::Response, &mut scratch) {
        Ok(u) if u.checksum.is_valid() => u.message.to_string(),
        Ok(u) => format!("{} ({})", u.message, u.checksum),
        Err(e) => format!("not a frame: {e}"),
    }
}

/// Explains bytes that hold no valid reply: a wrong checksum (and whether its bytes are
/// merely swapped), or a frame cut short.
pub fn explain_invalid(mode: Mode, rx: &[u8]) -> String {
    let shown = match mode {
        Mode::Rtu => Hex(rx).to_string(),
        Mode::Ascii => format!("{:?}", String::from_utf8_lossy(rx)),
    };
    let why = match mode {
        Mode::Rtu => match RtuFrame::new_checked(rx) {
            Ok(f) if f.checksum().is_valid() => format!(
                "a frame that does not answer the request ({})",
                describe_reply(mode, rx)
            ),
            Ok(f) => {
                let swapped = f.carried_crc().swap_bytes() == f.computed_crc();
                format!(
                    "{}{}",
                    f.checksum(),
                    if swapped {
                        " (the two CRC bytes are swapped)"
                    } else {
                        ""
                    }
                )
            }
            Err(e) => e.to_string(),
        },
        Mode::Ascii => match rx.iter().position(|&c| c == b':') {
            None => "no ':' start character".to_string(),
            Some(s) => match AsciiFrame::new_checked(&rx[s..]) {
                Ok(f) => {
                    let c = f.checksum();
                    if c.is_valid() {
                        "a frame that does not answer the request".to_string()
                    } else {
                        let b = f.as_bytes();
                        let n = b.len();
                        let mut fixed = b.to_vec();
                        fixed.swap(n - 4, n - 3);
                        let swapped = crate::codec::ascii::is_valid_frame(&fixed);
                        format!(
                            "{c}{}",
                            if swapped {
                                " (the two LRC characters are swapped)"
                            } else {
                                ""
                            }
                        )
                    }
                }
                Err(e) => e.to_string(),
            },
        },
    };
    format!("{} bytes without a valid reply: {shown}: {why}", rx.len())
}

/// Address, function and data of a frame whose structure is sound (checksum not checked).
pub fn body_of(mode: Mode, frame: &[u8]) -> Option<Vec<u8>> {
    codec::frame_parts(mode, frame).ok().map(|p| p.body)
}

/// [`body_of`], borrowed from `frame` where it can be (RTU); decoded (ASCII).
pub fn body_cow(mode: Mode, frame: &[u8]) -> Option<std::borrow::Cow<'_, [u8]>> {
    match mode {
        Mode::Rtu => RtuFrame::new_checked(frame)
            .ok()
            .map(|_| std::borrow::Cow::Borrowed(&frame[..frame.len() - 2])),
        Mode::Ascii => body_of(mode, frame).map(std::borrow::Cow::Owned),
    }
}

/// Bytes for a report line: hex in RTU, the characters in ASCII.
pub fn show(mode: Mode, bytes: &[u8]) -> String {
    match mode {
        Mode::Rtu => Hex(bytes).to_string(),
        Mode::Ascii => format!("{:?}", String::from_utf8_lossy(bytes)),
    }
}
