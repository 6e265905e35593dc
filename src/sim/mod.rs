//! The simulated vehicle: the model lives in `skyfuse_core::sim` (re-exported here);
//! [`publish`] puts its samples on Zenoh in the real bridges' formats.

pub use skyfuse_core::sim::*;

pub mod fleet;
pub mod publish;
