//! Recorded flights as samples: PX4 logs (ULog, or their CSV export), ArduPilot
//! DataFlash logs, skyfuse recordings and rosbag2 bags (MCAP), and MAVLink
//! telemetry logs.
pub mod dataflash;
pub mod mcap;
pub mod px4log;
pub mod tlog;

use crate::sample::Sample;

/// Sorts samples by stamp, stably (equal stamps keep their order), in place, moving each
/// sample about once: a sample is large (about 800 bytes, the odometry covariances), and
/// a sort that moves them n·log n times took longer than reading the log.
pub fn sort_by_stamp(samples: &mut [Sample]) {
    if samples.windows(2).all(|w| w[0].stamp_us <= w[1].stamp_us) {
        return;
    }
    // The index breaks ties, so the unstable sort of the keys is a stable sort.
    let mut order: Vec<_> = samples
        .iter()
        .enumerate()
        .map(|(i, s)| (s.stamp_us, i))
        .collect();
    order.sort_unstable();
    // Position k takes the sample now at from[k]: follow each cycle of the permutation.
    let mut from: Vec<usize> = order.into_iter().map(|(_, i)| i).collect();
    const DONE: usize = usize::MAX;
    for start in 0..from.len() {
        let mut k = start;
        while from[k] != DONE {
            let next = from[k];
            from[k] = DONE;
            if next == start {
                break;
            }
            samples.swap(k, next);
            k = next;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::sample::{Range, SensorData};

    fn sample(source: &str, stamp_us: Option<i64>) -> Sample {
        Sample {
            source: source.into(),
            stamp_us,
            arrival_us: 0,
            data: SensorData::Range(Range {
                distance_m: 1.0,
                min_m: None,
                max_m: None,
                signal_quality: None,
                variance: None,
                orientation: None,
            }),
        }
    }

    #[test]
    fn sorting_by_stamp_is_stable_and_keeps_every_sample() {
        let mut v = vec![
            sample("a", Some(30)),
            sample("b", Some(10)),
            sample("c", None),
            sample("d", Some(10)),
            sample("e", Some(20)),
            sample("f", Some(10)),
        ];
        let mut expected = v.clone();
        expected.sort_by_key(|s| s.stamp_us);
        sort_by_stamp(&mut v);
        let names = |v: &[Sample]| v.iter().map(|s| s.source.to_string()).collect::<Vec<_>>();
        assert_eq!(names(&v), ["c", "b", "d", "f", "e", "a"]);
        assert_eq!(v, expected);
        // Many cycles, many ties: the same as the standard library's stable sort.
        let mut v: Vec<Sample> = (0..2_000_u64)
            .map(|i| {
                let stamp = (i.wrapping_mul(2_654_435_761) % 97) as i64;
                sample(&i.to_string(), (i % 13 != 0).then_some(stamp))
            })
            .collect();
        let mut expected = v.clone();
        expected.sort_by_key(|s| s.stamp_us);
        sort_by_stamp(&mut v);
        assert_eq!(names(&v), names(&expected));
    }
}
