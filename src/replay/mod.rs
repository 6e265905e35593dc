//! Recorded flights as samples.
pub mod px4csv;
