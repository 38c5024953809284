//! Several simulated drives on one bus: every frame reaches every drive, each judges it
//! by its own node address and state and answers what is addressed to it, as drives on
//! one RS-485 pair do. A quirk can be planted on one node (`QUIRK@NODE`) or on all.

use std::fmt;
use std::time::Instant;

use super::drive::{Drive, Outcome, Quirk, QuirkError};
use crate::codec::{frame_parts, Mode};

/// What the server loop hands frames to: one drive, or a bus of them.
pub trait Responder {
    /// Handles one request frame (checksum included) received at `now`.
    fn handle(&mut self, mode: Mode, frame: &[u8], now: Instant) -> Outcome;
    /// Advances the drives' clocks (motor ramps).
    fn tick(&mut self, now: Instant);
    /// Whether a drive takes frames broken by a silence over t1.5 (the ignore-t15 quirk).
    fn ignores_t15(&self) -> bool;
}

impl Responder for Drive {
    fn handle(&mut self, mode: Mode, frame: &[u8], now: Instant) -> Outcome {
        Drive::handle(self, mode, frame, now)
    }

    fn tick(&mut self, now: Instant) {
        Drive::tick(self, now);
    }

    fn ignores_t15(&self) -> bool {
        self.quirks().contains(&Quirk::IgnoreT15)
    }
}

/// Drives at distinct node addresses on one line.
pub struct Bus {
    drives: Vec<Drive>,
}

/// Why a bus cannot be built.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum BusError {
    /// No drive.
    #[error("a bus needs at least one drive")]
    Empty,
    /// Two drives at one address.
    #[error("two drives at node {0:02X}H: each node address is one drive")]
    SameAddress(u8),
    /// A quirk planted on a node the bus does not have.
    #[error("--quirk {0}: node {1} is not on the bus (its nodes: {2})")]
    NoSuchNode(String, u8, String),
}

impl Bus {
    /// A bus of `drives` (distinct addresses).
    pub fn new(drives: Vec<Drive>) -> Result<Self, BusError> {
        if drives.is_empty() {
            return Err(BusError::Empty);
        }
        for (i, d) in drives.iter().enumerate() {
            if drives[..i].iter().any(|e| e.address() == d.address()) {
                return Err(BusError::SameAddress(d.address()));
            }
        }
        Ok(Bus { drives })
    }

    /// Drives of `model` at `nodes`, each answering after `delay` on `line` (paced or not,
    /// see [`Drive::with_line`]), with the quirks of `planted` that apply to it; a quirk
    /// planted on a node not in `nodes` is refused.
    pub fn of_model(
        model: &std::sync::Arc<crate::model::DriveModel>,
        nodes: &[u8],
        delay: std::time::Duration,
        planted: &[PlantedQuirk],
        line: crate::codec::timing::LineSettings,
        paced: bool,
    ) -> Result<Self, BusError> {
        check_planted(planted, nodes)?;
        Bus::new(
            nodes
                .iter()
                .map(|&n| {
                    Drive::new(model.clone(), n, delay)
                        .with_quirks(&quirks_for(planted, n))
                        .with_line(line, paced)
                })
                .collect(),
        )
    }

    /// The drives, in the order given.
    pub fn drives(&self) -> &[Drive] {
        &self.drives
    }

    /// The node addresses.
    pub fn addresses(&self) -> Vec<u8> {
        self.drives.iter().map(Drive::address).collect()
    }
}

impl From<Drive> for Bus {
    /// A bus of one drive.
    fn from(drive: Drive) -> Self {
        Bus {
            drives: vec![drive],
        }
    }
}

/// The quirks of `planted` that apply to `node`.
pub fn quirks_for(planted: &[PlantedQuirk], node: u8) -> Vec<Quirk> {
    planted
        .iter()
        .filter(|p| p.node.is_none_or(|n| n == node))
        .map(|p| p.quirk)
        .collect()
}

/// Checks that every quirk planted on one node names a node of `nodes`.
pub fn check_planted(planted: &[PlantedQuirk], nodes: &[u8]) -> Result<(), BusError> {
    for p in planted {
        if let Some(n) = p.node {
            if !nodes.contains(&n) {
                let list: Vec<String> = nodes.iter().map(u8::to_string).collect();
                return Err(BusError::NoSuchNode(p.to_string(), n, list.join(",")));
            }
        }
    }
    Ok(())
}

impl Responder for Bus {
    fn handle(&mut self, mode: Mode, frame: &[u8], now: Instant) -> Outcome {
        let several = self.drives.len() > 1;
        let to = frame_parts(mode, frame)
            .ok()
            .and_then(|p| p.body.first().copied());
        let mut judged = None;
        let mut sends = Vec::new();
        let mut notes = Vec::new();
        for d in &mut self.drives {
            let address = d.address();
            let o = d.handle(mode, frame, now);
            // The log shows the judgement of the node the frame is for (the first
            // node's for a broadcast or an address nobody has).
            if judged.is_none() || to == Some(address) {
                judged = Some(o.judgement);
            }
            // A drive's remarks about a frame for another node (its dead quirk, say) are
            // noise in the log, unless it sent something.
            let concerned = !several || to == Some(address) || to == Some(0) || !o.sends.is_empty();
            sends.extend(o.sends);
            notes.extend(o.notes.into_iter().filter(|_| concerned).map(|n| {
                if several {
                    format!("node {address:02X}H: {n}")
                } else {
                    n
                }
            }));
        }
        // Transmissions go out in time order (two drives answering at once collide on a
        // real line; here they follow each other).
        sends.sort_by_key(|s| s.after);
        Outcome {
            judgement: judged.unwrap_or_else(|| {
                // Unreachable (a bus has a drive), but never a panic on input.
                self.drives[0]
                    .model()
                    .judge(self.drives[0].address(), mode, frame)
            }),
            sends,
            notes,
        }
    }

    fn tick(&mut self, now: Instant) {
        for d in &mut self.drives {
            d.tick(now);
        }
    }

    fn ignores_t15(&self) -> bool {
        self.drives.iter().any(|d| d.ignores_t15())
    }
}

/// A quirk planted on every node of the bus, or on one: `dead@5`, `wrong-value-at=2520H@2`.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PlantedQuirk {
    /// The quirk.
    pub quirk: Quirk,
    /// The node it is planted on (None: every node).
    pub node: Option<u8>,
}

impl From<Quirk> for PlantedQuirk {
    /// A quirk on every node.
    fn from(quirk: Quirk) -> Self {
        PlantedQuirk { quirk, node: None }
    }
}

impl std::str::FromStr for PlantedQuirk {
    type Err = QuirkError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s.rsplit_once('@') {
            None => Ok(PlantedQuirk {
                quirk: s.parse()?,
                node: None,
            }),
            Some((q, n)) => {
                let node = parse_node(n).ok_or_else(|| {
                    QuirkError(format!(
                        "{s} (after '@' comes a node address 1..=247, decimal or hex with H)"
                    ))
                })?;
                Ok(PlantedQuirk {
                    quirk: q.parse()?,
                    node: Some(node),
                })
            }
        }
    }
}

impl fmt::Display for PlantedQuirk {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self.node {
            Some(n) => write!(f, "{}@{n}", self.quirk),
            None => write!(f, "{}", self.quirk),
        }
    }
}

/// A node address: decimal, or hex with H suffix or 0x prefix; not 0 (broadcast).
fn parse_node(text: &str) -> Option<u8> {
    let t = text.trim();
    let n = if let Some(h) = t
        .strip_prefix("0x")
        .or_else(|| t.strip_prefix("0X"))
        .or_else(|| t.strip_suffix(['H', 'h']))
    {
        u8::from_str_radix(h, 16).ok()?
    } else {
        t.parse().ok()?
    };
    (n != 0).then_some(n)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codec::pdu::{Message, Pdu};
    use crate::model::DriveModel;
    use std::sync::Arc;
    use std::time::Duration;

    fn bus(nodes: &[u8], planted: &[PlantedQuirk]) -> Bus {
        let model = Arc::new(DriveModel::builtin("f510").unwrap());
        Bus::new(
            nodes
                .iter()
                .map(|&n| {
                    Drive::new(model.clone(), n, Duration::ZERO)
                        .with_quirks(&quirks_for(planted, n))
                })
                .collect(),
        )
        .unwrap()
    }

    fn read(address: u8) -> Vec<u8> {
        Message {
            address,
            pdu: Pdu::ReadRequest {
                start: 0x2520,
                count: 1,
            },
        }
        .to_frame_vec(Mode::Rtu)
        .unwrap()
    }

    fn write(address: u8, value: u16) -> Vec<u8> {
        Message {
            address,
            pdu: Pdu::WriteSingle {
                register: 0x2502,
                value,
            },
        }
        .to_frame_vec(Mode::Rtu)
        .unwrap()
    }

    #[test]
    fn each_node_answers_its_own_address_only() {
        let mut b = bus(&[1, 2, 5], &[]);
        let now = Instant::now();
        for n in [1u8, 2, 5] {
            let o = b.handle(Mode::Rtu, &read(n), now);
            assert_eq!(o.sends.len(), 1, "node {n}");
            assert_eq!(o.sends[0].bytes[0], n);
        }
        assert!(b.handle(Mode::Rtu, &read(3), now).sends.is_empty());
        assert!(b.handle(Mode::Rtu, &read(0), now).sends.is_empty());
    }

    #[test]
    fn state_is_per_node_and_a_broadcast_reaches_all() {
        let mut b = bus(&[1, 2], &[]);
        let now = Instant::now();
        b.handle(Mode::Rtu, &write(1, 0x1111), now);
        assert_eq!(b.drives()[0].read_register(0x2502), 0x1111);
        assert_ne!(b.drives()[1].read_register(0x2502), 0x1111);
        let o = b.handle(Mode::Rtu, &write(0, 0x2222), now);
        assert!(o.sends.is_empty(), "a broadcast is not answered");
        assert!(b.drives().iter().all(|d| d.read_register(0x2502) == 0x2222));
    }

    #[test]
    fn a_quirk_planted_on_one_node_stays_there() {
        let planted: Vec<PlantedQuirk> = vec!["dead@2".parse().unwrap()];
        assert_eq!(planted[0].to_string(), "dead@2");
        let mut b = bus(&[1, 2], &planted);
        let now = Instant::now();
        assert_eq!(b.handle(Mode::Rtu, &read(1), now).sends.len(), 1);
        let o = b.handle(Mode::Rtu, &read(2), now);
        assert!(o.sends.is_empty());
        assert!(o
            .notes
            .iter()
            .any(|n| n.starts_with("node 02H: quirk dead")));
        assert!(check_planted(&planted, &[1, 2]).is_ok());
        let e = check_planted(&planted, &[1, 3]).unwrap_err();
        assert!(e.to_string().contains("node 2 is not on the bus"), "{e}");
    }

    #[test]
    fn planted_quirks_parse() {
        let p: PlantedQuirk = "wrong-value-at=2520H@0AH".parse().unwrap();
        assert_eq!(p.node, Some(10));
        assert_eq!(p.quirk, Quirk::WrongValueAt(0x2520));
        let p: PlantedQuirk = "crc-swap".parse().unwrap();
        assert_eq!(p.node, None);
        assert!("dead@0".parse::<PlantedQuirk>().is_err());
        assert!("dead@x".parse::<PlantedQuirk>().is_err());
        assert!("nonsense@2".parse::<PlantedQuirk>().is_err());
        assert_eq!(
            Bus::new(vec![]).err(),
            Some(BusError::Empty),
            "an empty bus is refused"
        );
    }
}
