use super::*;
use crate::sample::SensorKind;
use crate::sim::dataflash::{write_flight, BOOT_OFFSET_US};
use crate::sim::sensors::{StreamSpec, DEMO_STREAMS};
use crate::sim::{SimEvent, Simulator};
use proptest::prelude::*;

/// The demo's streams and a barometer: every kind the writer has a record for.
fn streams() -> Vec<StreamSpec> {
    let mut s = DEMO_STREAMS.to_vec();
    s.push(StreamSpec {
        input_id: "baro",
        kind: SensorKind::Baro,
        rate_hz: 20.0,
        delay_s: 0.01,
    });
    s
}

fn simulated(seconds: f64) -> (Vec<SimEvent>, Vec<u8>) {
    let events: Vec<SimEvent> = Simulator::new(&streams(), 11, seconds).collect();
    let mut bytes = Vec::new();
    let summary = write_flight(events.clone().into_iter(), &mut bytes).expect("written");
    assert_eq!(summary.bytes as usize, bytes.len());
    assert_eq!(summary.skipped, 0);
    (events, bytes)
}

fn no_progress(_: u64, _: u64) {}

/// A simulated flight written as a DataFlash log reads back sample for sample, each as
/// it was to the log's resolution (centidegrees, centimetres, 1e-7 degrees, f32).
#[test]
fn a_simulated_flight_reads_back_as_it_was_written() {
    let (events, bytes) = simulated(3.0);
    assert!(looks_like_dataflash(&bytes));
    let log = parse(&bytes, &mut no_progress);
    assert_eq!(log.scan.skipped_bytes, 0);
    assert_eq!(log.scan.cut_short, None);
    assert_eq!(log.scan.bad_formats, 0);
    assert!(log.unusable.is_empty(), "{:?}", log.first_unusable);
    // The truth, as SITL logs it (SIM, 10 Hz), besides every sensor sample.
    let truth: Vec<_> = log
        .samples
        .iter()
        .filter(|s| s.source.as_ref() == "sim_truth")
        .collect();
    assert_eq!(log.samples.len(), events.len() + truth.len());
    assert!((29..=31).contains(&truth.len()), "{}", truth.len());
    let origin = crate::geo::LocalEnu::new(
        crate::sim::sensors::HOME_LAT,
        crate::sim::sensors::HOME_LON,
        crate::sim::sensors::HOME_ALT,
    );
    for s in &truth {
        let t = (s.stamp_us.unwrap() - BOOT_OFFSET_US as i64) as f64 * 1e-6;
        let e = events
            .iter()
            .find(|e| (e.measured_t - t).abs() < 1e-6)
            .expect("an event then");
        let SensorData::AutopilotEstimate(a) = &s.data else {
            panic!()
        };
        let (lat, lon, alt) = a.geodetic.unwrap();
        // 1e-7° is 1.1 cm; the altitude an f32 near 500 m.
        assert!((origin.to_enu(lat, lon, alt) - e.truth.position).norm() < 0.02);
        let yaw = e.truth.attitude.euler_angles().2;
        assert!((a.yaw.unwrap() - yaw).abs() < 1e-5, "{a:?}");
    }
    for kind in [
        SensorKind::Imu,
        SensorKind::Attitude,
        SensorKind::Odometry,
        SensorKind::Flow,
        SensorKind::Range,
        SensorKind::Gnss,
        SensorKind::Baro,
    ] {
        let mut written: Vec<&SimEvent> = events.iter().filter(|e| e.data.kind() == kind).collect();
        written.sort_by(|a, b| a.measured_t.total_cmp(&b.measured_t));
        let read: Vec<_> = log
            .samples
            .iter()
            .filter(|s| s.data.kind() == kind && s.source.as_ref() != "sim_truth")
            .collect();
        assert!(!read.is_empty(), "{kind:?}");
        assert_eq!(read.len(), written.len(), "{kind:?}");
        for (r, w) in read.iter().zip(&written) {
            let t = (w.measured_t * 1e6).round() as i64 + BOOT_OFFSET_US as i64;
            assert_eq!(r.stamp_us, Some(t), "{kind:?}");
            let close = |a: Vector3<f64>, b: Vector3<f64>, tol: f64| {
                (a - b).norm() < tol * (1.0 + b.norm())
            };
            match (&r.data, &w.data) {
                (SensorData::Imu(a), SensorData::Imu(b)) => {
                    assert!(close(a.gyro.unwrap(), b.gyro.unwrap(), 1e-6), "{a:?} {b:?}");
                    assert!(
                        close(a.accel.unwrap(), b.accel.unwrap(), 1e-6),
                        "{a:?} {b:?}"
                    );
                }
                (SensorData::Attitude(a), SensorData::Attitude(b)) => {
                    // Centidegrees: 1e-4 rad per angle.
                    assert!(a.orientation.angle_to(&b.orientation) < 4e-4, "{a:?} {b:?}");
                }
                (SensorData::Odometry(a), SensorData::Odometry(b)) => {
                    assert!(close(a.position, b.position, 1e-6), "{a:?} {b:?}");
                    assert!(a.orientation.angle_to(&b.orientation) < 1e-5);
                }
                (SensorData::Flow(a), SensorData::Flow(b)) => {
                    let (ra, rb) = (a.rate.unwrap(), b.rate.unwrap());
                    assert!((ra - rb).norm() < 1e-5 * (1.0 + rb.norm()), "{a:?} {b:?}");
                    match (a.gyro, b.gyro) {
                        (Some(ga), Some(gb)) => {
                            assert!((ga - gb).xy().norm() < 1e-5, "{a:?} {b:?}")
                        }
                        // Without a gyro of its own, OF logs the vehicle's body rates.
                        (None, Some(_)) => panic!("gyro lost: {a:?} {b:?}"),
                        _ => {}
                    }
                    assert_eq!(a.quality, b.quality);
                    // The interval is the records' spacing (OF has no integration time).
                    let dt = a.integration_s.unwrap();
                    assert!(dt > 0.0 && dt < 0.5, "{dt}");
                }
                (SensorData::Range(a), SensorData::Range(b)) => {
                    assert!(
                        (a.distance_m - b.distance_m).abs() <= 0.005 + 1e-9,
                        "{a:?} {b:?}"
                    );
                    assert_eq!(a.max_m, b.max_m);
                    assert_eq!(a.min_m, b.min_m);
                    assert_eq!(a.signal_quality == Some(1), b.signal_quality == Some(1));
                }
                (SensorData::Gnss(a), SensorData::Gnss(b)) => {
                    assert!((a.lat_deg - b.lat_deg).abs() < 1e-7);
                    assert!((a.lon_deg - b.lon_deg).abs() < 1e-7);
                    assert!((a.alt_m - b.alt_m).abs() <= 0.005 + 1e-9);
                    assert_eq!(a.fix, b.fix);
                    if let (Some(va), Some(vb)) = (a.velocity, b.velocity) {
                        assert!(close(va, vb, 1e-5), "{a:?} {b:?}");
                    }
                }
                (SensorData::Baro(a), SensorData::Baro(b)) => {
                    assert!((a.pressure_pa - b.pressure_pa).abs() < 0.01, "{a:?} {b:?}");
                }
                (a, b) => panic!("{a:?} read for {b:?}"),
            }
        }
    }
}

/// A log the end of the file cuts in the middle of a record says where, and keeps
/// every record before it.
#[test]
fn a_log_cut_in_a_record_says_where() {
    let (_, bytes) = simulated(1.0);
    let whole = parse(&bytes, &mut no_progress);
    let cut = &bytes[..bytes.len() * 2 / 3];
    let log = parse(cut, &mut no_progress);
    let at = log.scan.cut_short.expect("cut short") as usize;
    assert!(
        at < cut.len() && cut.len() - at < 128,
        "{at} of {}",
        cut.len()
    );
    assert_eq!(&cut[at..at + 2], &[HEAD1, HEAD2]);
    assert!(log.samples.len() > whole.samples.len() / 2);
    assert!(log.samples.len() < whole.samples.len());
    // A log that ends between two records is complete as far as anyone can tell.
    let log = parse(&bytes[..at], &mut no_progress);
    assert_eq!(log.scan.cut_short, None);
}

/// Garbage between records (a corrupt card, padding) is skipped, counted, and costs
/// nothing else; so are the records of a type no valid FMT defined.
#[test]
fn garbage_between_records_is_skipped_and_counted() {
    let (_, bytes) = simulated(1.0);
    let whole = parse(&bytes, &mut no_progress);
    // The end of the first data record past byte 2000: a boundary between records.
    let mut ends = Vec::new();
    walk(
        &bytes,
        &mut |r| {
            ends.push(r.payload.as_ptr() as usize - bytes.as_ptr() as usize + r.format.len - 3)
        },
        &mut no_progress,
    );
    let at = *ends
        .iter()
        .find(|&&e| e > 2000)
        .expect("a record past 2000");
    let garbage = [0x00, 0xA3, 0x11, 0xA3, 0x95, 0xFE, 0x42, 0xFF, 0xFF];
    let mut corrupt = bytes[..at].to_vec();
    corrupt.extend_from_slice(&garbage);
    corrupt.extend_from_slice(&bytes[at..]);
    let log = parse(&corrupt, &mut no_progress);
    assert_eq!(log.samples, whole.samples);
    assert_eq!(log.scan.skipped_bytes, garbage.len() as u64);
    // `A3 95 FE`: a header of a type nobody defined.
    assert_eq!(log.scan.undefined_records, 1);
}

/// Builds a log from FMT definitions and records, for layouts the writer does not make.
fn fmt(id: u8, name: &str, types: &str, labels: &str, len: u8) -> Vec<u8> {
    let mut b = vec![HEAD1, HEAD2, FMT_TYPE, id, len];
    for (text, width) in [(name, 4), (types, 16), (labels, 64)] {
        let mut f = text.as_bytes().to_vec();
        f.resize(width, 0);
        b.extend_from_slice(&f);
    }
    b
}

fn record(id: u8, fields: &[&[u8]]) -> Vec<u8> {
    let mut b = vec![HEAD1, HEAD2, id];
    for f in fields {
        b.extend_from_slice(f);
    }
    b
}

/// An FMT whose length its types do not fill is refused and named; its records are
/// skipped, counted, and the rest of the log reads.
#[test]
fn an_fmt_that_does_not_add_up_is_refused_and_named() {
    // ArduPilot's logs define FMT itself first: that is no error.
    let mut b = fmt(
        FMT_TYPE,
        "FMT",
        "BBnNZ",
        "Type,Length,Name,Format,Columns",
        89,
    );
    b.extend(fmt(10, "BARO", "Qf", "TimeUS,Press", 3 + 8 + 4 + 1));
    b.extend(fmt(11, "BAR2", "QfX", "TimeUS,Press,What", 3 + 8 + 4 + 4));
    b.extend(fmt(12, "ATT", "QccC", "TimeUS,Roll,Pitch,Yaw", 3 + 14));
    let baro = record(
        10,
        &[&5_000_000u64.to_le_bytes(), &101_000f32.to_le_bytes(), &[0]],
    );
    b.extend(&baro);
    b.extend(record(
        12,
        &[
            &5_000_000u64.to_le_bytes(),
            &1000i16.to_le_bytes(),
            &0i16.to_le_bytes(),
            &9000u16.to_le_bytes(),
        ],
    ));
    let log = parse(&b, &mut no_progress);
    assert_eq!(log.scan.bad_formats, 2);
    let why = log.scan.first_error.as_deref().unwrap();
    assert!(
        why.contains("BARO") && why.contains("length 16") && why.contains("take 15"),
        "{why}"
    );
    assert_eq!(log.messages.get("ATT"), Some(&1));
    assert!(!log.messages.contains_key("BARO"));
    // The BARO record's header is found, its type is not defined: counted, skipped.
    assert_eq!(log.scan.undefined_records, 1);
    assert_eq!(log.samples.len(), 1);
    let SensorData::Attitude(a) = &log.samples[0].data else {
        panic!()
    };
    // Roll 10°, facing east (NED yaw 90° = ENU yaw 0).
    let (r, _, y) = a.orientation.euler_angles();
    assert!(
        (y - 0.0).abs() < 1e-9 && r.abs() > 0.1,
        "{:?}",
        a.orientation.euler_angles()
    );
}

/// Logs before 2016: `TimeMS`, one RFND record with `Dist1` in centimetres, `IMU2`
/// without an instance field, GPS with `Status`/`Lat`/`Lng`/`Alt`.
#[test]
fn an_older_layout_reads_by_its_labels() {
    let mut b = fmt(
        1,
        "IMU2",
        "Iffffff",
        "TimeMS,GyrX,GyrY,GyrZ,AccX,AccY,AccZ",
        3 + 28,
    );
    b.extend(fmt(2, "RFND", "ICC", "TimeMS,Dist1,Dist2", 3 + 8));
    b.extend(fmt(
        3,
        "GPS",
        "BIHBcLLeeEefI",
        "Status,TimeMS,Week,NSats,HDop,Lat,Lng,RelAlt,Alt,Spd,GCrs,VZ,T",
        3 + 42,
    ));
    b.extend(fmt(4, "PARM", "Nf", "Name,Value", 3 + 20));
    let mut name = b"RNGFND_MAX_CM".to_vec();
    name.resize(16, 0);
    b.extend(record(4, &[&name, &700f32.to_le_bytes()]));
    let f = |v: f32| v.to_le_bytes();
    b.extend(record(
        1,
        &[
            &1234u32.to_le_bytes(),
            &f(0.1),
            &f(0.2),
            &f(0.3),
            &f(0.0),
            &f(0.0),
            &f(-9.8),
        ],
    ));
    b.extend(record(
        2,
        &[
            &1240u32.to_le_bytes(),
            &153u16.to_le_bytes(),
            &0u16.to_le_bytes(),
        ],
    ));
    b.extend(record(
        3,
        &[
            &[3],
            &403_369_800u32.to_le_bytes(),
            &1800u16.to_le_bytes(),
            &[9],
            &150i16.to_le_bytes(),
            &(473_977_420i32).to_le_bytes(),
            &(85_455_940i32).to_le_bytes(),
            &500i32.to_le_bytes(),
            &48_800i32.to_le_bytes(),
            &250u32.to_le_bytes(),
            &9000i32.to_le_bytes(),
            &f(0.5),
            &1250u32.to_le_bytes(),
        ],
    ));
    let log = parse(&b, &mut no_progress);
    assert_eq!(log.scan.bad_formats, 0, "{:?}", log.scan.first_error);
    assert!(log.unusable.is_empty(), "{:?}", log.first_unusable);
    let by = |src: &str| {
        log.samples
            .iter()
            .find(|s| s.source.as_ref() == src)
            .unwrap_or_else(|| panic!("{src}: {:?}", log.samples))
    };
    let imu = by("imu_1");
    assert_eq!(imu.stamp_us, Some(1_234_000));
    let SensorData::Imu(i) = &imu.data else {
        panic!()
    };
    assert!((i.accel.unwrap().z - 9.8).abs() < 1e-5, "FRD → FLU: {i:?}");
    assert!((i.gyro.unwrap().y + 0.2).abs() < 1e-6);
    let SensorData::Range(r) = &by("range").data else {
        panic!()
    };
    assert!((r.distance_m - 1.53).abs() < 1e-9);
    let SensorData::Gnss(g) = &by("gps").data else {
        panic!()
    };
    assert!((g.lat_deg - 47.397_742).abs() < 1e-9 && (g.alt_m - 488.0).abs() < 1e-9);
    assert_eq!(g.fix, GnssFixType::Fix3d);
    // 2.5 m/s on course 90° (east), climbing 0.5 m/s (VZ is down).
    let v = g.velocity.unwrap();
    assert!((v - Vector3::new(2.5, 0.0, -0.5)).norm() < 1e-6, "{v}");
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]
    /// Any bytes: no panic, and every byte is a record, skipped, or past a cut.
    #[test]
    fn any_bytes_parse_without_panic(bytes in proptest::collection::vec(any::<u8>(), 0..2048)) {
        let log = parse(&bytes, &mut no_progress);
        prop_assert!(log.scan.skipped_bytes <= bytes.len() as u64);
    }

    /// A real log with bytes flipped: no panic, and never more samples than records.
    #[test]
    fn a_damaged_log_parses_without_panic(flips in proptest::collection::vec((any::<prop::sample::Index>(), any::<u8>()), 1..16)) {
        let (_, mut bytes) = simulated(0.3);
        for (i, b) in flips {
            let i = i.index(bytes.len());
            bytes[i] = b;
        }
        let log = parse(&bytes, &mut no_progress);
        prop_assert!(log.samples.len() as u64 <= log.scan.records);
    }
}
