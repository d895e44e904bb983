//! Error types. Every error names what it is about (the file, and the place inside it) and, where
//! there is one, says how to fix it.

use std::path::PathBuf;

mod mesh;

pub use mesh::{MeshError, Place};

/// A defect in the bytes of an `.oavm` file: found at open (header, section table, level table),
/// by `verify`, or by the tracer's bounds checks while it walks the tree.
#[derive(Debug, thiserror::Error)]
pub enum FormatError {
    #[error(
        "the file is {len} bytes, shorter than a {need}-byte header: not an .oavm file, or truncated"
    )]
    TooShort { len: u64, need: u64 },
    #[error("bad magic bytes {found:02x?}: not an .oavm file")]
    BadMagic { found: [u8; 8] },
    #[error(
        "format version {found} is not supported: this oavm reads version {expected}; \
         repack the mesh with this version's oavm-pack"
    )]
    Version { expected: u32, found: u32 },
    #[error("this oavm reads .oavm files on little-endian machines only")]
    BigEndianHost,
    #[error("header: {0}")]
    Header(String),
    #[error("section table: {0}")]
    SectionTable(String),
    #[error("{section} section: {what}")]
    Section { section: &'static str, what: String },
    #[error(
        "{section}: checksum mismatch (stored {stored:#018x}, computed {computed:#018x}): \
         the file is corrupt"
    )]
    Checksum {
        section: &'static str,
        stored: u64,
        computed: u64,
    },
    #[error("corrupt {0}")]
    Corrupt(String),
}

/// Everything that can go wrong in the library, with the file it concerns.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    #[error(transparent)]
    Mesh(#[from] MeshError),
    #[error("{}: {source}", path.display())]
    Format {
        path: PathBuf,
        #[source]
        source: FormatError,
    },
    #[error("{}: {source}", path.display())]
    Io {
        path: PathBuf,
        #[source]
        source: std::io::Error,
    },
    /// An output file that cannot (or must not) be written.
    #[error("{}: {what}", path.display())]
    Output { path: PathBuf, what: String },
    /// A mapped input that changed while it was read: what it gave cannot be trusted.
    #[error("{}: {source}", path.display())]
    Changed {
        path: PathBuf,
        #[source]
        source: crate::os::Changed,
    },
    /// A memory budget too small for the file: it must hold three of its largest blocks (one
    /// being read, one being admitted, one more to evict from), each in whole pages.
    #[error(
        "{}: a memory budget of {budget} bytes is too small for this file: its largest block \
         decodes to {largest} bytes and tracing needs room for three (in whole pages); give a budget of {needed} \
         bytes or more (--mem-budget)",
        path.display()
    )]
    Budget {
        path: PathBuf,
        budget: u64,
        needed: u64,
        largest: u64,
    },
    #[error("{0}")]
    Build(String),
    #[error("{0}")]
    Invalid(String),
}

impl Error {
    /// The messages of the error's sources that its own message does not already carry,
    /// outermost first: what a program prints after the error itself.
    pub fn causes(&self) -> Vec<String> {
        let text = self.to_string();
        let mut out: Vec<String> = Vec::new();
        let mut src = std::error::Error::source(self);
        while let Some(s) = src {
            let s_text = s.to_string();
            if !text.contains(&s_text) && !out.iter().any(|o| o.contains(&s_text)) {
                out.push(s_text);
            }
            src = s.source();
        }
        out
    }

    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Error {
        Error::Io {
            path: path.into(),
            source,
        }
    }

    pub fn format(path: impl Into<PathBuf>, source: FormatError) -> Error {
        Error::Format {
            path: path.into(),
            source,
        }
    }
}

pub type Result<T, E = Error> = std::result::Result<T, E>;
