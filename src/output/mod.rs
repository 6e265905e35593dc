//! Outputs: the fused pose to the machines and people that use it.
//!
//! - [`vpe`]: pure conversion of the fused pose to MAVLink messages (NED/FRD).
//! - [`mavlink_out`]: the MAVLink endpoints (UDP, TCP, serial, mavlink-server on Zenoh).
//! - [`zenoh_out`]: JSON and ROS 2 CDR on Zenoh.

pub mod mavlink_out;
pub mod vpe;
pub mod zenoh_out;
