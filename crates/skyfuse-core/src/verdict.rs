//! The vocabulary of a verdict on a sensor: its state and the reasons for it. Its own
//! module so that what speaks of health (events, the ingest layer's transport view)
//! need not depend on the health checks, which read the estimator's status.

use serde::Serialize;

/// Health of one sensor.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum HealthState {
    Ok,
    Degraded,
    Failed,
    Stale,
    NoData,
    Disabled,
}

impl HealthState {
    pub fn as_str(self) -> &'static str {
        match self {
            HealthState::Ok => "ok",
            HealthState::Degraded => "degraded",
            HealthState::Failed => "failed",
            HealthState::Stale => "stale",
            HealthState::NoData => "no_data",
            HealthState::Disabled => "disabled",
        }
    }

    /// Whether the estimator may fuse a sensor in this state.
    pub fn usable(self) -> bool {
        matches!(self, HealthState::Ok | HealthState::Degraded)
    }

    pub(crate) fn rank(self) -> u8 {
        match self {
            HealthState::Ok => 0,
            HealthState::Degraded => 1,
            HealthState::Failed => 2,
            HealthState::Stale => 3,
            HealthState::NoData => 3,
            HealthState::Disabled => 4,
        }
    }
}

/// Why a sensor is not ok.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Reason {
    pub code: &'static str,
    pub text: String,
}
