//! Geometry kernels shared by the builder, the tracer and every structure we compare against:
//! rays, the watertight ray–triangle test and the exact triangle–box overlap test.

pub mod brute;
pub mod ray;
pub mod reference;
pub mod triangle;
pub mod tribox;

pub use ray::{AGREEMENT_TOLERANCE, Hit, Ray};
