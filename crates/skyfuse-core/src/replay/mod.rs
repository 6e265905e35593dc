//! Recorded flights as samples: PX4 logs (ULog, or their CSV export) and MAVLink
//! telemetry logs.
pub mod px4log;
pub mod tlog;
