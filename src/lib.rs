//! oavm: a ray-tracing acceleration structure that lives in a file.
//!
//! The crate follows the three layers of the OAVM paper (Yuan et al., Acta Optica Sinica 2017):
//!
//! - [`physical`]: the bytes on disk, specified in `format-spec.md`: records, writing, mapping
//!   the file, validation and verification;
//! - [`mapping`]: `(level, Morton code) -> record index` without per-node pointers, and the
//!   parent, child and neighbour queries on Morton codes;
//! - [`logical`]: the octree with merged empty volumes as the tracer sees it, and the tracer.
//!
//! Beside them: [`mesh`] reads meshes, [`pack`] turns a mesh into the physical bytes (and
//! updates a packed file in place), [`render`] makes images with the tracer, [`geom`] holds the
//! geometry kernels every part shares, [`progress`] reports long work.
//!
//! ```no_run
//! # fn main() -> Result<(), oavm::Error> {
//! use oavm::pack::{PackOptions, Quiet, pack};
//! pack("data/bunny.ply".as_ref(), "bunny.oavm".as_ref(), &PackOptions::default(), &Quiet)?;
//! let scene = oavm::Scene::open("bunny.oavm")?;
//! # Ok(()) }
//! ```
//!
//! `examples/minimal.rs` traces a batch of rays through such a file.

#![deny(unsafe_code)]

#[allow(unsafe_code)]
pub mod os;

pub mod error;
pub mod geom;
pub mod logical;
pub mod mapping;
pub mod mesh;
pub mod output;
pub mod pack;
pub mod physical;
pub mod progress;
pub mod rays;
pub mod render;

pub use error::{Error, FormatError};
pub use geom::{Hit, HitAttributes, Ray};
pub use logical::{Counters, Scene};
pub use mesh::Mesh;
pub use pack::{BuildOptions, BuildStats};
