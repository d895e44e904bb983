//! Being written; see the module list in `compare/mod.rs`.
