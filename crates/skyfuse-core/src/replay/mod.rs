//! Recorded flights as samples: PX4 logs (ULog, or their CSV export) and MAVLink
//! telemetry logs.
pub mod mcap;
pub mod px4log;
pub mod tlog;
