//! All vector files together, from the copies built into the binary or from a directory.

use std::path::Path;

use super::model::{FlagsFile, LoadError, Vector, VectorFile, DOCUMENTS};

/// The vector files as they were when the binary was built (`vectors/` at the top of
/// the workspace), so the suite needs no files at run time.
const BUILTIN: [(&str, &str); 5] = [
    ("f510.json", include_str!("../../../vectors/f510.json")),
    ("a510.json", include_str!("../../../vectors/a510.json")),
    ("l510.json", include_str!("../../../vectors/l510.json")),
    ("e510.json", include_str!("../../../vectors/e510.json")),
    (
        "l510-legacy.json",
        include_str!("../../../vectors/l510-legacy.json"),
    ),
];
const BUILTIN_FLAGS: &str = include_str!("../../../vectors/flags.json");

/// Every vector file and the flags table.
#[derive(Debug, Clone)]
pub struct VectorSet {
    /// The flags table.
    pub flags: FlagsFile,
    /// One file per document, in [`DOCUMENTS`] order.
    pub files: Vec<VectorFile>,
}

impl VectorSet {
    /// The vectors built into the binary.
    pub fn builtin() -> Result<Self, LoadError> {
        Self::from_texts(BUILTIN_FLAGS, Self::builtin_texts())
    }

    /// The texts of the built-in vector files, as (file name, JSON).
    pub fn builtin_texts() -> Vec<(String, String)> {
        BUILTIN
            .iter()
            .map(|(n, t)| (n.to_string(), t.to_string()))
            .collect()
    }

    /// Loads `flags.json` and `<document>.json` for every document from `dir`.
    pub fn load_dir(dir: &Path) -> Result<Self, LoadError> {
        let read = |name: &str| {
            let path = dir.join(name);
            std::fs::read_to_string(&path).map_err(|source| LoadError::Io {
                file: path.display().to_string(),
                source,
            })
        };
        let flags = read("flags.json")?;
        let mut texts = Vec::new();
        for d in DOCUMENTS {
            let name = format!("{d}.json");
            let text = read(&name)?;
            texts.push((name, text));
        }
        Self::from_texts(&flags, texts)
    }

    /// Parses the flags table and the files given as (name, text).
    pub fn from_texts(
        flags_text: &str,
        files: impl IntoIterator<Item = (String, String)>,
    ) -> Result<Self, LoadError> {
        let flags: FlagsFile =
            serde_json::from_str(flags_text).map_err(|source| LoadError::Json {
                file: "flags.json".into(),
                source,
            })?;
        let mut parsed = Vec::new();
        for (name, text) in files {
            let f = VectorFile::from_json(&name, &text, &flags)?;
            if parsed.iter().any(|p: &VectorFile| p.document == f.document) {
                return Err(LoadError::Format {
                    file: name,
                    problem: format!("document {} is given twice", f.document),
                });
            }
            parsed.push(f);
        }
        parsed.sort_by_key(|f| DOCUMENTS.iter().position(|d| *d == f.document));
        Ok(VectorSet {
            flags,
            files: parsed,
        })
    }

    /// Every vector with its file, in file order.
    pub fn iter(&self) -> impl Iterator<Item = (&VectorFile, &Vector)> {
        self.files
            .iter()
            .flat_map(|f| f.vectors.iter().map(move |v| (f, v)))
    }

    /// The vector with this id.
    pub fn get(&self, id: &str) -> Option<&Vector> {
        self.iter().map(|(_, v)| v).find(|v| v.id == id)
    }

    /// The file of a document.
    pub fn file(&self, document: &str) -> Option<&VectorFile> {
        self.files.iter().find(|f| f.document == document)
    }
}
