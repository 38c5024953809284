//! Why a saved report cannot be read back: shared by the report's reader and the
//! reader of its expectations section.

/// Why a JSON value is not a report.
#[derive(Debug, thiserror::Error)]
pub enum ReportError {
    /// The text is not JSON.
    #[error("not JSON: {0}")]
    Json(#[from] serde_json::Error),
    /// The JSON is not a report of this suite.
    #[error("not a conformance report: {0}")]
    NotAReport(String),
    /// A field is missing or has the wrong type or value.
    #[error("{path}: {problem}")]
    Field {
        /// Where, e.g. `checks[3].status`.
        path: String,
        /// What is wrong.
        problem: String,
    },
}

/// A [`ReportError::Field`] at `path`.
pub(crate) fn field(path: &str, problem: impl Into<String>) -> ReportError {
    ReportError::Field {
        path: path.to_string(),
        problem: problem.into(),
    }
}
