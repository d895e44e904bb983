//! Corrupted `.oavm` files (format-spec.md §11; hostile input): every part of the format
//! damaged, in one test binary with a file per part it damages (`header`, `blocks`, `top`,
//! `occluders`, `prims`, and `anywhere` for the sweeps over every region). What must hold, the
//! files damaged and how the runs report are in the module doc of [`fixtures`], with the
//! fixtures and the harness the files share. One binary, not one per file: each would compile
//! the fixtures again.
//!
//!     cargo test --test corruption [header::|blocks::|top::|occluders::|prims::|anywhere::]

#[path = "../common/mod.rs"]
mod common;
mod fixtures;

mod anywhere;
mod blocks;
mod geometries;
mod header;
mod occluders;
mod prims;
mod top;
