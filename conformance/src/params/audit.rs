//! The audit log of restores: an append-only file of JSON lines, one per register
//! written. Each line is written, flushed and synced before the next write goes out, so
//! that a restore stopped at any point (SIGTERM, a lost link, a power cut of the host)
//! leaves whole lines that say what was sent.

use std::io::Write;
use std::path::{Path, PathBuf};

use serde::Serialize;

/// One register written (or refused), as a line of the audit log.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct AuditRecord {
    /// When the reply came (RFC 3339, UTC, microseconds).
    pub time: String,
    /// The node written to.
    pub node: u8,
    /// The register, 4 hex digits.
    pub register: String,
    /// The value it held before (read just before the write).
    pub old: u16,
    /// The value written.
    pub new: u16,
    /// 06H or 10H.
    pub function: String,
    /// The request frame, bytes in hex (ASCII frames as their characters' bytes).
    pub request: String,
    /// The reply frame, bytes in hex; empty where none came.
    pub reply: String,
    /// What came of it, in words ("written, read back 0005H", "exception 02H ...").
    pub outcome: String,
    /// Whether the read-back showed the value written.
    pub verified: bool,
    /// Whether this write undid an earlier one of the same restore (after an interruption).
    pub undo: bool,
}

/// The audit log, open for appending.
pub struct AuditLog {
    path: PathBuf,
    file: std::fs::File,
}

impl AuditLog {
    /// Opens (or creates) `path` for appending; what was there stays.
    pub fn open(path: &Path) -> std::io::Result<AuditLog> {
        let file = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(path)?;
        Ok(AuditLog {
            path: path.to_path_buf(),
            file,
        })
    }

    /// Where it is.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// Appends one line in one write, and flushes and syncs it.
    pub fn append(&mut self, record: &AuditRecord) -> std::io::Result<()> {
        let mut line = serde_json::to_vec(record).map_err(std::io::Error::other)?;
        line.push(b'\n');
        // One write call per line: an append-mode write lands whole at the end of the file.
        self.file.write_all(&line)?;
        self.file.flush()?;
        self.file.sync_data()
    }
}

/// The time now as the audit log writes it.
pub fn now() -> String {
    humantime::format_rfc3339_micros(std::time::SystemTime::now()).to_string()
}
