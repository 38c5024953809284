//! Markdown as the documentation tests read it: the repository's Markdown files, and a
//! page split into its prose and its fenced code blocks. Shared by tests/docs.rs (the
//! examples and options) and tests/docs_links.rs (the links).
#![allow(dead_code)]

use std::path::{Path, PathBuf};

/// The top of the repository.
pub fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .parent()
        .unwrap()
        .to_path_buf()
}

/// Every Markdown file of the repository that people read (not build output, not
/// installed packages, not fuzz corpora).
pub fn markdown_files() -> Vec<PathBuf> {
    fn walk(dir: &Path, out: &mut Vec<PathBuf>) {
        let Ok(entries) = std::fs::read_dir(dir) else {
            return;
        };
        for e in entries.flatten() {
            let p = e.path();
            let name = e.file_name().to_string_lossy().to_string();
            if p.is_dir() {
                if !(name.starts_with('.') && name != ".ci"
                    || matches!(name.as_str(), "target" | "node_modules" | "book")
                    || name.starts_with("corpus"))
                {
                    walk(&p, out);
                }
            } else if name.ends_with(".md") {
                out.push(p);
            }
        }
    }
    let mut out = Vec::new();
    walk(&repo(), &mut out);
    out.sort();
    out
}

/// `p` relative to the repository, as a failure names a file.
pub fn rel(p: &Path) -> String {
    p.strip_prefix(repo())
        .unwrap_or(p)
        .to_string_lossy()
        .to_string()
}

/// A fenced code block: its info string, the line of its opening fence (1-based), the
/// indent of that fence (a block in a list item) and its lines, less that indent.
pub struct Block {
    /// The info string.
    pub info: String,
    /// The line of the opening fence (1-based).
    pub line: usize,
    /// The indent of the opening fence.
    pub indent: usize,
    /// The lines, less that indent.
    pub lines: Vec<String>,
}

impl Block {
    /// The language: the info string's first word.
    pub fn lang(&self) -> &str {
        self.info.split([' ', ',']).next().unwrap_or("")
    }
}

/// Splits a Markdown text into the lines outside code blocks (with their line numbers)
/// and the fenced blocks.
pub fn split(text: &str) -> (Vec<(usize, String)>, Vec<Block>) {
    let mut prose = Vec::new();
    let mut blocks = Vec::new();
    let mut open: Option<(String, Block)> = None;
    for (i, line) in text.lines().enumerate() {
        let trimmed = line.trim_start();
        let indent = line.len() - trimmed.len();
        let fence: String = trimmed
            .chars()
            .take_while(|&c| c == '`' || c == '~')
            .collect();
        let is_fence = fence.len() >= 3 && fence.chars().all(|c| fence.starts_with(c));
        if let Some((f, mut b)) = open.take() {
            if is_fence
                && fence.len() >= f.len()
                && fence.starts_with(&f[..1])
                && trimmed[fence.len()..].trim().is_empty()
            {
                blocks.push(b);
            } else {
                b.lines.push(line[indent.min(b.indent)..].to_string());
                open = Some((f, b));
            }
        } else if is_fence {
            open = Some((
                fence.clone(),
                Block {
                    info: trimmed[fence.len()..].trim().to_string(),
                    line: i + 1,
                    indent,
                    lines: Vec::new(),
                },
            ));
        } else {
            prose.push((i + 1, line.to_string()));
        }
    }
    (prose, blocks)
}
