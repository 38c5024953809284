//! Made-up Ethernet, IPv4 and TCP headers around the bytes of one TCP connection, so that
//! a Modbus TCP (MBAP) conversation opens in Wireshark as Modbus/TCP.
//!
//! The suite speaks to a gateway through the operating system's socket, which shows the
//! stream, not its segments: the headers here are written by the suite, not captured.
//! What they carry is true where it can be: the addresses of the connection (IPv4; an IPv6
//! end is written as 127.0.0.1), the client's port, the stream's bytes in order, one
//! segment per write and per read, sequence and acknowledgement numbers that count those
//! bytes, and correct IPv4 and TCP checksums. What is made up: the MAC addresses
//! (locally administered 02:00:00:00:00:01 for the client, :02 for the server), the
//! initial sequence numbers, the three-way handshake written before the first segment,
//! and the server's port, always written as 502 so that Wireshark decodes Modbus/TCP
//! without settings (the real one is in the interface's description).

use std::net::Ipv4Addr;

/// Link type 1: Ethernet.
pub const LINKTYPE_ETHERNET: u16 = 1;

/// The Modbus/TCP port that the server side is written with.
pub const MODBUS_TCP_PORT: u16 = 502;

const CLIENT_MAC: [u8; 6] = [0x02, 0, 0, 0, 0, 0x01];
const SERVER_MAC: [u8; 6] = [0x02, 0, 0, 0, 0, 0x02];
const CLIENT_ISN: u32 = 0x1000_0000;
const SERVER_ISN: u32 = 0x2000_0000;

const SYN: u8 = 0x02;
const ACK: u8 = 0x10;
const PSH: u8 = 0x08;

/// One TCP connection's two directions, as segments with headers.
#[derive(Debug, Clone)]
pub struct TcpFlow {
    client: (Ipv4Addr, u16),
    server: (Ipv4Addr, u16),
    client_next: u32,
    server_next: u32,
    ip_id: u16,
}

impl TcpFlow {
    /// A flow from the client's address and port to the server's address (its port is
    /// written as [`MODBUS_TCP_PORT`]).
    pub fn new(client: (Ipv4Addr, u16), server: Ipv4Addr) -> Self {
        TcpFlow {
            client,
            server: (server, MODBUS_TCP_PORT),
            client_next: CLIENT_ISN,
            server_next: SERVER_ISN,
            ip_id: 1,
        }
    }

    /// The three packets of the handshake (SYN, SYN-ACK, ACK), to write first.
    pub fn handshake(&mut self) -> [Vec<u8>; 3] {
        let syn = self.segment(true, SYN, CLIENT_ISN, 0, &[]);
        let syn_ack = self.segment(false, SYN | ACK, SERVER_ISN, CLIENT_ISN + 1, &[]);
        let ack = self.segment(true, ACK, CLIENT_ISN + 1, SERVER_ISN + 1, &[]);
        self.client_next = CLIENT_ISN + 1;
        self.server_next = SERVER_ISN + 1;
        [syn, syn_ack, ack]
    }

    /// A segment of `payload` from the client (`from_client`) or the server, which
    /// acknowledges everything the other side sent so far.
    pub fn data(&mut self, from_client: bool, payload: &[u8]) -> Vec<u8> {
        let (seq, ack) = if from_client {
            (self.client_next, self.server_next)
        } else {
            (self.server_next, self.client_next)
        };
        let p = self.segment(from_client, PSH | ACK, seq, ack, payload);
        let next = seq.wrapping_add(payload.len() as u32);
        if from_client {
            self.client_next = next;
        } else {
            self.server_next = next;
        }
        p
    }

    fn segment(
        &mut self,
        from_client: bool,
        flags: u8,
        seq: u32,
        ack: u32,
        data: &[u8],
    ) -> Vec<u8> {
        let (src, dst) = if from_client {
            (self.client, self.server)
        } else {
            (self.server, self.client)
        };
        let (smac, dmac) = if from_client {
            (CLIENT_MAC, SERVER_MAC)
        } else {
            (SERVER_MAC, CLIENT_MAC)
        };
        // TCP header (20 bytes, no options).
        let mut tcp = Vec::with_capacity(20 + data.len());
        tcp.extend_from_slice(&src.1.to_be_bytes());
        tcp.extend_from_slice(&dst.1.to_be_bytes());
        tcp.extend_from_slice(&seq.to_be_bytes());
        tcp.extend_from_slice(&ack.to_be_bytes());
        tcp.push(5 << 4);
        tcp.push(flags);
        tcp.extend_from_slice(&0xFFFFu16.to_be_bytes());
        tcp.extend_from_slice(&[0, 0, 0, 0]); // checksum, urgent pointer
        tcp.extend_from_slice(data);
        let mut pseudo = Vec::with_capacity(12 + tcp.len());
        pseudo.extend_from_slice(&src.0.octets());
        pseudo.extend_from_slice(&dst.0.octets());
        pseudo.extend_from_slice(&[0, 6]);
        pseudo.extend_from_slice(&(tcp.len() as u16).to_be_bytes());
        pseudo.extend_from_slice(&tcp);
        let sum = internet_checksum(&pseudo);
        tcp[16..18].copy_from_slice(&sum.to_be_bytes());
        // IPv4 header (20 bytes).
        let total = (20 + tcp.len()) as u16;
        let mut ip = vec![0x45, 0];
        ip.extend_from_slice(&total.to_be_bytes());
        ip.extend_from_slice(&self.ip_id.to_be_bytes());
        self.ip_id = self.ip_id.wrapping_add(1);
        ip.extend_from_slice(&[0x40, 0, 64, 6, 0, 0]); // don't fragment, TTL, TCP
        ip.extend_from_slice(&src.0.octets());
        ip.extend_from_slice(&dst.0.octets());
        let sum = internet_checksum(&ip);
        ip[10..12].copy_from_slice(&sum.to_be_bytes());
        let mut frame = Vec::with_capacity(14 + ip.len() + tcp.len());
        frame.extend_from_slice(&dmac);
        frame.extend_from_slice(&smac);
        frame.extend_from_slice(&0x0800u16.to_be_bytes());
        frame.extend_from_slice(&ip);
        frame.extend_from_slice(&tcp);
        frame
    }
}

/// The Internet checksum (RFC 1071): the ones' complement of the ones' complement sum of
/// the 16-bit words (a last odd byte padded with zero).
pub fn internet_checksum(bytes: &[u8]) -> u16 {
    let mut sum: u32 = 0;
    for pair in bytes.chunks(2) {
        let word = u16::from_be_bytes([pair[0], pair.get(1).copied().unwrap_or(0)]);
        sum += u32::from(word);
    }
    while sum > 0xFFFF {
        sum = (sum & 0xFFFF) + (sum >> 16);
    }
    !(sum as u16)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_internet_checksum_of_a_known_ipv4_header() {
        // The example header of RFC 1071's usual illustration (Wikipedia, "IPv4 header
        // checksum"): 4500 0073 0000 4000 4011 [b861] c0a8 0001 c0a8 00c7.
        let h = [
            0x45, 0x00, 0x00, 0x73, 0x00, 0x00, 0x40, 0x00, 0x40, 0x11, 0x00, 0x00, 0xc0, 0xa8,
            0x00, 0x01, 0xc0, 0xa8, 0x00, 0xc7,
        ];
        assert_eq!(internet_checksum(&h), 0xb861);
        // A header that carries its checksum sums to zero.
        let mut with = h;
        with[10..12].copy_from_slice(&0xb861u16.to_be_bytes());
        assert_eq!(internet_checksum(&with), 0);
        assert_eq!(internet_checksum(&[0x01]), !0x0100);
    }

    #[test]
    fn segments_count_the_stream_and_carry_valid_checksums() {
        let mut f = TcpFlow::new((Ipv4Addr::new(127, 0, 0, 1), 40000), Ipv4Addr::LOCALHOST);
        let hs = f.handshake();
        assert_eq!(hs[0][14 + 20 + 13], SYN);
        assert_eq!(hs[1][14 + 20 + 13], SYN | ACK);
        let req = [0u8, 1, 0, 0, 0, 6, 1, 3, 0x25, 0x20, 0, 1];
        let p = f.data(true, &req);
        assert_eq!(p.len(), 14 + 20 + 20 + req.len());
        assert_eq!(&p[12..14], &[0x08, 0x00]);
        // IPv4 header and TCP segment (with its pseudo header) check.
        assert_eq!(internet_checksum(&p[14..34]), 0);
        let mut pseudo = Vec::new();
        pseudo.extend_from_slice(&p[26..34]);
        pseudo.extend_from_slice(&[0, 6]);
        pseudo.extend_from_slice(&((p.len() - 34) as u16).to_be_bytes());
        pseudo.extend_from_slice(&p[34..]);
        assert_eq!(internet_checksum(&pseudo), 0);
        // Ports: client's, then 502; seq after the SYN; the payload at the end.
        assert_eq!(&p[34..36], &40000u16.to_be_bytes());
        assert_eq!(&p[36..38], &502u16.to_be_bytes());
        assert_eq!(&p[38..42], &(CLIENT_ISN + 1).to_be_bytes());
        assert_eq!(&p[p.len() - req.len()..], &req);
        // The reply acknowledges the request's bytes; the next request follows them.
        let r = f.data(false, &[0u8, 1, 0, 0, 0, 5, 1, 3, 2, 0, 4]);
        assert_eq!(&r[34..36], &502u16.to_be_bytes());
        assert_eq!(
            &r[42..46],
            &(CLIENT_ISN + 1 + req.len() as u32).to_be_bytes()
        );
        let p2 = f.data(true, &req);
        assert_eq!(
            &p2[38..42],
            &(CLIENT_ISN + 1 + req.len() as u32).to_be_bytes()
        );
        assert_eq!(&p2[42..46], &(SERVER_ISN + 1 + 11).to_be_bytes());
    }
}
