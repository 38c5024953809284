//! Which description a model was read from: its file (or the built-in text), its title and
//! the SHA-256 of its bytes, so that a report names exactly the description it judged by.

use sha2::{Digest, Sha256};

/// The description a model was read from.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Source {
    /// The file as given on the command line; `None` for a model built into the binary.
    pub file: Option<String>,
    /// The description's title (what it is read from).
    pub title: String,
    /// SHA-256 of the description's bytes, lower-case hex (64 digits): two runs judged by
    /// the same description carry the same hash, whatever the file was called.
    pub sha256: String,
}

impl Source {
    /// The description `text`, read from `file` (`None`: built in), titled `title`.
    pub fn of(file: Option<&str>, title: &str, text: &[u8]) -> Self {
        Source {
            file: file.map(str::to_string),
            title: title.to_string(),
            sha256: sha256_hex(text),
        }
    }

    /// The file, or `built-in`, as reports print it.
    pub fn file_or_builtin(&self) -> &str {
        self.file.as_deref().unwrap_or("built-in")
    }
}

/// SHA-256 of `bytes` in lower-case hex.
pub fn sha256_hex(bytes: &[u8]) -> String {
    use std::fmt::Write as _;
    Sha256::digest(bytes)
        .iter()
        .fold(String::with_capacity(64), |mut s, b| {
            let _ = write!(s, "{b:02x}");
            s
        })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_hash_of_the_bytes() {
        // FIPS 180-2 appendix B.1: SHA-256("abc").
        assert_eq!(
            sha256_hex(b"abc"),
            "ba7816bf8f01cfea414140de5dae2223b00361a396177a9cb410ff61f20015ad"
        );
        let s = Source::of(None, "T", b"abc");
        assert_eq!(s.file_or_builtin(), "built-in");
        assert_eq!(
            Source::of(Some("a.json"), "T", b"").file_or_builtin(),
            "a.json"
        );
    }
}
