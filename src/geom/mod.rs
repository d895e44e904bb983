//! Geometry kernels shared by the builder, the tracer and every structure we compare against:
//! rays, the watertight ray–triangle test and the exact triangle–box overlap test.

pub mod ray;

pub use ray::{Hit, Ray};
