//! A ULog replayed without holding its samples: [`UlogSamples`].

use super::*;
use std::cell::RefCell;

/// A ULog's samples, made from its topics' kept columns as a replay reaches them, in
/// the order [`read_ulog_with_progress`] gives: the joins that reader makes afterwards
/// (the attitude's rates from `vehicle_angular_velocity`, the flow's gyro from EKF2,
/// `vehicle_imu` as the IMU) are made on each sample as it passes. The samples (168
/// bytes each, four million in an hour of a 1 kHz log) are never all in memory.
pub struct UlogSamples {
    /// The topics merged into samples (the joins' own topics are read up front).
    files: Vec<TopicFile>,
    /// `vehicle_angular_velocity`'s rows (time, FLU rate), for the attitude samples.
    rates: Vec<(i64, Vector3<f64>)>,
    /// EKF2's flow gyro integrals (time, FRD integral), for `flow` samples without one.
    flow_gyro: Vec<(i64, Vector3<f64>)>,
    /// `vehicle_imu` stands in for `sensor_combined` (absent): its sources become `imu`.
    imu_from_vehicle_imu: bool,
    rows: usize,
    /// The joins' topics' summaries, and each merged topic's from the latest pass, in
    /// reading order; flow samples given EKF2's gyro in the latest pass.
    read: RefCell<(Vec<TopicSummary>, usize)>,
    /// Every topic's name, in reading order.
    order: Vec<String>,
    /// Wanted topics the log does not have, as sentences.
    pub missing: Vec<String>,
}

/// A ULog for replay: streamed ([`UlogSamples`]) when every topic is in time order and
/// nothing has to stand in for `vehicle_attitude` (PX4's own logs); read whole
/// otherwise (the heading stand-in re-sorts the samples).
pub enum UlogRead {
    Streamed(UlogSamples),
    Whole(Px4Log),
}

/// Opens a ULog file for replay (see [`UlogRead`]); `progress` counts rows when it is
/// read whole.
pub fn read_ulog_for_replay(
    file: &Path,
    progress: &mut dyn FnMut(u64, u64),
) -> Result<UlogRead, Px4LogError> {
    let files = ulog_topic_files(file)?;
    let has = |t: &str| files.iter().any(|f| TOPICS[f.order.0].0 == t);
    let mut in_order = true;
    for tf in &files {
        in_order &= time_keys(tf)?.windows(2).all(|w| w[0] <= w[1]);
    }
    if !in_order || !has("vehicle_attitude") {
        return read_topics(files, progress).map(UlogRead::Whole);
    }
    let imu_from_vehicle_imu = !has("sensor_combined") && has("vehicle_imu");
    let missing = missing_topics(&has);
    let order = files.iter().map(|f| f.name.clone()).collect();
    let (joined, files): (Vec<TopicFile>, Vec<TopicFile>) = files
        .into_iter()
        .partition(|f| f.source == "angular_velocity" || f.source == EKF2_FLOW_GYRO);
    let (mut rates, mut flow_gyro, mut summaries) = (Vec::new(), Vec::new(), Vec::new());
    for tf in &joined {
        let rows = if tf.source == "angular_velocity" {
            &mut rates
        } else {
            &mut flow_gyro
        };
        let mut keep = |s: Sample| {
            if let (SensorData::Imu(i), Some(t)) = (&s.data, s.stamp_us) {
                rows.extend(i.gyro.map(|g| (t, g)));
            }
        };
        let read = merged(std::slice::from_ref(tf), &mut keep)?;
        summaries.extend(read.into_iter().flatten());
    }
    let rows = files.iter().map(TopicFile::ulog_rows).sum();
    Ok(UlogRead::Streamed(UlogSamples {
        files,
        rates,
        flow_gyro,
        imu_from_vehicle_imu,
        rows,
        read: RefCell::new((summaries, 0)),
        order,
        missing,
    }))
}

/// `files`' samples in time order into `sink` (see `read_ulog_merged`), without
/// progress: a streamed replay reports its own.
fn merged(
    files: &[TopicFile],
    sink: &mut dyn FnMut(Sample),
) -> Result<Option<Vec<TopicSummary>>, Px4LogError> {
    let mut quiet = |_: u64, _: u64| {};
    let mut prog = Progress {
        done: 0,
        total: 0,
        reported: 0,
        cb: &mut quiet,
    };
    read_ulog_merged(files, sink, &mut prog, true)
}

impl UlogSamples {
    /// What each topic contributed, in reading order: taken (once) after a pass over
    /// the samples.
    pub fn take_topics(&self) -> Vec<TopicSummary> {
        let mut topics = std::mem::take(&mut self.read.borrow_mut().0);
        topics.sort_by_key(|t| self.order.iter().position(|n| *n == t.name));
        topics
    }

    /// Stand-ins used for absent topics, as sentences (after a pass over the samples).
    pub fn stand_ins(&self) -> Vec<String> {
        let mut out = Vec::new();
        if self.read.borrow().1 > 0 {
            out.push(FLOW_GYRO_STAND_IN.to_string());
        }
        if self.imu_from_vehicle_imu {
            out.push(IMU_STAND_IN.to_string());
        }
        out
    }
}

impl UlogSamples {
    /// `vehicle_imu`'s sources become `imu`'s when it stands in for `sensor_combined`:
    /// each new name made once (`renamed`: from, to).
    fn rename_imu(&self, s: &mut Sample, renamed: &mut Vec<(Arc<str>, Arc<str>)>) {
        if !self.imu_from_vehicle_imu {
            return;
        }
        if let Some(to) = imu_name(&s.source) {
            let at = renamed
                .iter()
                .position(|(from, _)| Arc::ptr_eq(from, &s.source));
            let at = at.unwrap_or_else(|| {
                renamed.push((s.source.clone(), Arc::from(to)));
                renamed.len() - 1
            });
            s.source = renamed[at].1.clone();
        }
    }
}

impl crate::offline::SampleSource for UlogSamples {
    fn for_each(&self, f: &mut dyn FnMut(&Sample)) {
        let mut renamed = Vec::new();
        let given_gyro = std::cell::Cell::new(0);
        let mut pass = |mut s: Sample| {
            match &mut s.data {
                SensorData::Attitude(a) if s.source.as_ref() == "attitude" => {
                    if let Some(t) = s.stamp_us {
                        attach_rate(a, &self.rates, t);
                    }
                }
                SensorData::Flow(fl) if s.source.as_ref() == "flow" => {
                    if let Some(t) = s.stamp_us {
                        if attach_flow_gyro(fl, &self.flow_gyro, t) {
                            given_gyro.set(given_gyro.get() + 1);
                        }
                    }
                }
                _ => {}
            }
            self.rename_imu(&mut s, &mut renamed);
            f(&s);
        };
        // The files' mappers were made when it was opened: reading cannot fail now.
        if let Ok(Some(read)) = merged(&self.files, &mut pass) {
            let mut kept = self.read.borrow_mut();
            kept.0
                .retain(|t| !self.files.iter().any(|f| f.name == t.name));
            kept.0.extend(read);
            kept.1 = given_gyro.get();
        }
    }

    fn len_hint(&self) -> usize {
        self.rows
    }

    /// Topic after topic, in the merge's order of files: a merge's tie goes to the
    /// earlier file. Without the joins (a survey does not read what they add).
    fn for_each_in_runs(&self, f: &mut dyn FnMut(&Sample)) -> bool {
        let mut renamed = Vec::new();
        for tf in &self.files {
            let mut pass = |mut s: Sample| {
                self.rename_imu(&mut s, &mut renamed);
                f(&s);
            };
            let _ = merged(std::slice::from_ref(tf), &mut pass);
        }
        true
    }
}
