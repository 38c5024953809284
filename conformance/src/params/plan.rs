//! Which requests a backup and a restore send: bounded 03H reads over the parameters,
//! and the fewest 06H or 10H writes that change only the registers that differ.

use super::Parameter;
use crate::codec::hex::Hex;
use crate::codec::pdu::{Message, Pdu, Registers};
use crate::codec::Mode;
use crate::model::DriveModel;

/// Why no write plan could be made.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum PlanError {
    /// The model serves neither 06H nor 10H.
    #[error("the {model} model serves neither 06H nor 10H (its functions: {functions}): nothing can be written")]
    NoWriteFunction {
        /// The model.
        model: String,
        /// Its functions, in hex.
        functions: String,
    },
    /// A frame could not be built.
    #[error("cannot build the write of {count} registers from {start:04X}H: {why}")]
    Frame {
        /// First register.
        start: u16,
        /// Registers.
        count: usize,
        /// The codec's reason.
        why: String,
    },
}

/// One write of a restore: the registers from `start`, their values before and after,
/// and the frame that carries it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PlannedWrite {
    /// First register.
    pub start: u16,
    /// The values the device holds now (as read for the plan).
    pub old: Vec<u16>,
    /// The values to write.
    pub new: Vec<u16>,
    /// 06H or 10H.
    pub function: u8,
    /// The request frame, in the mode of the plan.
    pub frame: Vec<u8>,
}

impl PlannedWrite {
    /// The registers it writes.
    pub fn registers(&self) -> impl Iterator<Item = u16> + '_ {
        (0..self.new.len()).map(move |i| self.start.wrapping_add(i as u16))
    }

    /// The frame as the runner prints one (hex in RTU, the text in ASCII).
    pub fn shown(&self, mode: Mode) -> String {
        crate::judge::show(mode, &self.frame)
    }

    /// The frame's bytes in hex.
    pub fn hex(&self) -> String {
        Hex(&self.frame).to_string()
    }
}

/// Runs of registers, each consecutive within one group, at most `limit` long.
fn runs(params: &[&Parameter], limit: usize) -> Vec<(u16, usize)> {
    let mut out: Vec<(u16, usize, &str)> = Vec::new();
    for p in params {
        match out.last_mut() {
            Some((start, n, group))
                if *group == p.group
                    && *n < limit
                    && usize::from(*start) + *n == usize::from(p.register) =>
            {
                *n += 1
            }
            _ => out.push((p.register, 1, &p.group)),
        }
    }
    out.into_iter().map(|(s, n, _)| (s, n)).collect()
}

/// The 03H reads that cover `params` in `mode`: consecutive registers of one group, at
/// most the model's registers per read, never across a register the model leaves out
/// (a hole, or a reserved or write-only register).
pub fn read_plan(model: &DriveModel, mode: Mode, params: &[Parameter]) -> Vec<(u16, u16)> {
    let limit = usize::from(model.limits.read.get(mode).max(1));
    let all: Vec<&Parameter> = params.iter().collect();
    runs(&all, limit)
        .into_iter()
        .map(|(s, n)| (s, u16::try_from(n).unwrap_or(1)))
        .collect()
}

/// The writes that take the device from `current` to `wanted`, for the registers where
/// they differ: consecutive ones of a group in one 10H request (up to the model's limit)
/// where the model serves 10H, else one 06H each; a single register by 06H where the
/// model serves it. `changes` is (parameter, current value, wanted value), in register
/// order.
pub fn write_plan(
    model: &DriveModel,
    mode: Mode,
    node: u8,
    changes: &[(&Parameter, u16, u16)],
) -> Result<Vec<PlannedWrite>, PlanError> {
    let single = model.functions.contains(&0x06);
    let multiple = model.functions.contains(&0x10);
    if !single && !multiple {
        return Err(PlanError::NoWriteFunction {
            model: model.id.clone(),
            functions: model
                .functions
                .iter()
                .map(|f| format!("{f:02X}H"))
                .collect::<Vec<_>>()
                .join(", "),
        });
    }
    let limit = if multiple {
        usize::from(model.limits.write.get(mode).max(1))
    } else {
        1
    };
    let params: Vec<&Parameter> = changes.iter().map(|(p, ..)| *p).collect();
    let mut out = Vec::new();
    let mut i = 0;
    for (start, n) in runs(&params, limit) {
        let part = &changes[i..i + n];
        i += n;
        let old: Vec<u16> = part.iter().map(|(_, o, _)| *o).collect();
        let new: Vec<u16> = part.iter().map(|(_, _, w)| *w).collect();
        let bytes: Vec<u8> = new.iter().flat_map(|v| v.to_be_bytes()).collect();
        let (function, pdu) = if n == 1 && single {
            (
                0x06,
                Pdu::WriteSingle {
                    register: start,
                    value: new[0],
                },
            )
        } else {
            let values = Registers::new(&bytes).map_err(|e| PlanError::Frame {
                start,
                count: n,
                why: e.to_string(),
            })?;
            (0x10, Pdu::WriteMultipleRequest { start, values })
        };
        let frame = Message { address: node, pdu }
            .to_frame_vec(mode)
            .map_err(|e| PlanError::Frame {
                start,
                count: n,
                why: e.to_string(),
            })?;
        out.push(PlannedWrite {
            start,
            old,
            new,
            function,
            frame,
        });
    }
    Ok(out)
}
