//! Geometry kernels shared by the builder, the tracer and every structure we compare against:
//! rays and hits ([`ray`], the records of `RAYS.md`), the watertight ray–triangle test
//! ([`triangle`]) and the exact triangle–box overlap test ([`tribox`]); the wide kernels of the
//! format 4 tracer, the watertight test on a group of eight triangles ([`group`]) and the
//! conservative ray–box test on a node's eight children ([`wide_box`]), each as SSE, AVX2 and
//! portable code with identical answers; and the f64 reference every test measures them
//! against ([`reference`]), which shares no code with them.

pub mod group;
pub mod ray;
pub mod reference;
pub mod triangle;
pub mod tribox;
pub mod wide_box;

pub use group::TriGroupView;
pub use ray::{AGREEMENT_TOLERANCE, AllHits, Hit, HitAttributes, ListedHit, Ray};
pub use wide_box::{BoxRay, ClusterNodeView, FmaRay};
