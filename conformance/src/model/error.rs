//! Why a model file is not a valid model.

/// Why a model file is not a valid model.
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    /// Not JSON, or not of the file format.
    #[error("{model}: not a valid model file")]
    Json {
        /// The model or file.
        model: String,
        /// What serde said.
        source: serde_json::Error,
    },
    /// A rule of the format is broken.
    #[error("{model}: {}{problem}", if path.is_empty() { String::new() } else { format!("{path}: ") })]
    Invalid {
        /// The model.
        model: String,
        /// The JSON path of the field at fault ("blocks[2].last",
        /// "limits.read_registers.rtu"), empty where the problem is not one field's;
        /// `model lint` maps it to a line and column of the file.
        path: String,
        /// What is wrong.
        problem: String,
    },
    /// `model lint` found errors: every finding, errors and warnings, one per line.
    #[error("{file}: {} in the description\n{}", crate::model::lint::summary(findings), findings.iter().map(ToString::to_string).collect::<Vec<_>>().join("\n"))]
    Lint {
        /// The file.
        file: String,
        /// What lint found.
        findings: Vec<crate::model::lint::Finding>,
    },
    /// No such model.
    #[error("unknown model {0:?}; the models are f510, a510, l510, e510, l510-legacy")]
    Unknown(String),
    /// The file could not be read.
    #[error("cannot read {file}")]
    Io {
        /// The file.
        file: String,
        /// The error.
        source: std::io::Error,
    },
}

impl ModelError {
    /// The JSON path of the field at fault, where the error is about one field.
    pub fn path(&self) -> Option<&str> {
        match self {
            ModelError::Invalid { path, .. } if !path.is_empty() => Some(path),
            _ => None,
        }
    }
}
