//! Taps: where the data path hands copies to the flight recorder and the Foxglove live
//! view ([`crate::record`]) without ever waiting. Each tap puts an item on a bounded
//! queue with `try_send`; a full queue drops the item and counts it.

use crate::estimator::{DebugSeries, FusedPose};
use crate::sample::Sample;
use std::sync::atomic::{AtomicU64, Ordering::Relaxed};
use std::sync::Arc;

/// What the taps hand to the recorder thread.
#[derive(Debug)]
pub enum TapItem {
    /// An input's payload exactly as it arrived on `key`.
    Input {
        arrival_us: i64,
        input: usize,
        key: String,
        payload: Vec<u8>,
    },
    /// A sample ingest accepted.
    Decoded {
        input: usize,
        sample: Box<Sample>,
    },
    Pose(Arc<FusedPose>),
    /// A MAVLink frame skyfuse sent, at the host time it went out.
    MavlinkOut {
        sent_us: i64,
        frame: Arc<[u8]>,
    },
    /// Health (the status API's view) or an event, as JSON, at a host time.
    Health {
        t_us: i64,
        json: serde_json::Value,
    },
    Event {
        t_us: i64,
        json: serde_json::Value,
    },
    Debug {
        t_us: i64,
        series: Arc<DebugSeries>,
    },
    /// A ROS 2 output skyfuse published on Zenoh (CDR of `ros_type` on `key`).
    Ros2Out {
        t_us: i64,
        key: String,
        ros_type: crate::codec::RosType,
        payload: Vec<u8>,
    },
    /// Shutdown: finalise the file.
    Finish,
}

/// Counters of the recorder thread and its queue, for the status API and /metrics.
#[derive(Debug, Default)]
pub struct TapStats {
    /// Items that found the queue full (never recorded).
    pub dropped: AtomicU64,
    /// Messages logged to the channels.
    pub logged: AtomicU64,
    /// Bytes of finished files plus the current file's size on disk.
    pub bytes: AtomicU64,
    pub files: AtomicU64,
    /// The file being written, and the last error (a full disk, an unwritable dir).
    pub file: std::sync::Mutex<Option<String>>,
    pub error: std::sync::Mutex<Option<String>>,
}

/// The taps' handle: cheap to clone, a no-op when neither recording nor live view is on.
#[derive(Clone, Default)]
pub struct Tap {
    inner: Option<(std::sync::mpsc::SyncSender<TapItem>, Arc<TapStats>)>,
}

impl std::fmt::Debug for Tap {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(if self.inner.is_some() {
            "Tap(on)"
        } else {
            "Tap(off)"
        })
    }
}

impl Tap {
    /// A tap that records nothing.
    pub fn off() -> Self {
        Self::default()
    }

    pub(crate) fn new(tx: std::sync::mpsc::SyncSender<TapItem>, stats: Arc<TapStats>) -> Self {
        Self {
            inner: Some((tx, stats)),
        }
    }

    pub fn is_on(&self) -> bool {
        self.inner.is_some()
    }

    fn send(&self, item: TapItem) {
        if let Some((tx, stats)) = &self.inner {
            if tx.try_send(item).is_err() {
                stats.dropped.fetch_add(1, Relaxed);
            }
        }
    }

    pub fn input(&self, arrival_us: i64, input: usize, key: &str, payload: &[u8]) {
        if self.is_on() {
            self.send(TapItem::Input {
                arrival_us,
                input,
                key: key.to_string(),
                payload: payload.to_vec(),
            });
        }
    }

    pub fn decoded(&self, input: usize, sample: &Sample) {
        if self.is_on() {
            self.send(TapItem::Decoded {
                input,
                sample: Box::new(sample.clone()),
            });
        }
    }

    pub fn pose(&self, pose: Arc<FusedPose>) {
        self.send(TapItem::Pose(pose));
    }

    pub fn mavlink_out(&self, sent_us: i64, frame: &Arc<[u8]>) {
        if self.is_on() {
            self.send(TapItem::MavlinkOut {
                sent_us,
                frame: frame.clone(),
            });
        }
    }

    pub fn ros2_out(&self, t_us: i64, key: &str, ros_type: crate::codec::RosType, payload: &[u8]) {
        if self.is_on() {
            self.send(TapItem::Ros2Out {
                t_us,
                key: key.to_string(),
                ros_type,
                payload: payload.to_vec(),
            });
        }
    }

    pub fn health(&self, t_us: i64, json: serde_json::Value) {
        self.send(TapItem::Health { t_us, json });
    }

    pub fn event(&self, t_us: i64, json: serde_json::Value) {
        self.send(TapItem::Event { t_us, json });
    }

    pub fn debug(&self, t_us: i64, series: Arc<DebugSeries>) {
        self.send(TapItem::Debug { t_us, series });
    }
}
