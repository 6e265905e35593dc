//! `GET /metrics`: the service's numbers in the OpenMetrics text format, for Prometheus
//! (or anything that scrapes it). Built at each scrape from the same typed [`Status`]
//! that `/api/v1/status` serialises, so the two never disagree, and encoded by the
//! official `prometheus-client` crate (names, `_total` suffixes, escaping, `# EOF`).

use super::state::Status;
use crate::health::HealthState;
use crate::output::OutputDetail;
use prometheus_client::encoding::text::encode;
use prometheus_client::metrics::counter::Counter;
use prometheus_client::metrics::family::Family;
use prometheus_client::metrics::gauge::Gauge;
use prometheus_client::registry::{Registry, Unit};
use std::sync::atomic::AtomicU64;

/// What Prometheus asks for and gets.
pub const CONTENT_TYPE: &str = "application/openmetrics-text; version=1.0.0; charset=utf-8";

type Labels = Vec<(&'static str, String)>;
type Counters = Family<Labels, Counter>;
type Gauges = Family<Labels, Gauge<f64, AtomicU64>>;

/// Every health state, so a sensor's state is a set of 0/1 gauges (one is 1).
const STATES: [HealthState; 6] = [
    HealthState::Ok,
    HealthState::Degraded,
    HealthState::Failed,
    HealthState::Stale,
    HealthState::NoData,
    HealthState::Disabled,
];

/// The process's own CPU time and resident memory (Linux `/proc/self`), if readable.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct ProcessStats {
    pub cpu_seconds: f64,
    pub resident_bytes: f64,
}

impl ProcessStats {
    pub fn read() -> Option<Self> {
        // utime and stime are fields 14 and 15 of /proc/self/stat, after the
        // parenthesised command name (which may hold spaces).
        let stat = std::fs::read_to_string("/proc/self/stat").ok()?;
        let rest = stat.rsplit_once(')')?.1;
        let fields: Vec<&str> = rest.split_whitespace().collect();
        let ticks: f64 =
            fields.get(11)?.parse::<f64>().ok()? + fields.get(12)?.parse::<f64>().ok()?;
        let statm = std::fs::read_to_string("/proc/self/statm").ok()?;
        let pages: f64 = statm.split_whitespace().nth(1)?.parse().ok()?;
        // USER_HZ and the page size: 100 and 4 KiB on every Linux this runs on.
        Some(Self {
            cpu_seconds: ticks / 100.0,
            resident_bytes: pages * 4096.0,
        })
    }
}

struct Metrics {
    registry: Registry,
}

impl Metrics {
    fn counters(&mut self, name: &str, help: &str) -> Counters {
        let f = Counters::default();
        self.registry.register(name, help, f.clone());
        f
    }

    fn gauges(&mut self, name: &str, help: &str) -> Gauges {
        let f = Gauges::default();
        self.registry.register(name, help, f.clone());
        f
    }

    fn gauges_unit(&mut self, name: &str, help: &str, unit: Unit) -> Gauges {
        let f = Gauges::default();
        self.registry
            .register_with_unit(name, help, unit, f.clone());
        f
    }

    fn gauge(&mut self, name: &str, help: &str, v: f64) {
        let g: Gauge<f64, AtomicU64> = Gauge::default();
        g.set(v);
        self.registry.register(name, help, g);
    }

    fn counter(&mut self, name: &str, help: &str, v: u64) {
        let c: Counter = Counter::default();
        c.inc_by(v);
        self.registry.register(name, help, c);
    }
}

fn flag(b: bool) -> f64 {
    if b {
        1.0
    } else {
        0.0
    }
}

/// The text a scrape gets.
pub fn render(status: &Status, process: Option<ProcessStats>) -> String {
    let mut m = Metrics {
        registry: Registry::with_prefix("skyfuse"),
    };
    let svc = &status.service;
    m.gauges(
        "build_info",
        "Version and vehicle of this service (always 1)",
    )
    .get_or_create(&vec![
        ("version", svc.version.to_string()),
        ("vehicle", svc.vehicle.clone()),
    ])
    .set(1.0);
    let uptime: Gauge<f64, AtomicU64> = Gauge::default();
    uptime.set(svc.uptime_s);
    m.registry.register_with_unit(
        "uptime",
        "Time since the service started",
        Unit::Seconds,
        uptime,
    );
    m.gauge(
        "zenoh_routers",
        "Zenoh routers this session is connected to",
        svc.zenoh.routers as f64,
    );
    m.gauge(
        "zenoh_peers",
        "Zenoh peers this session is connected to",
        svc.zenoh.peers as f64,
    );

    let ing = &status.ingest;
    m.gauge(
        "ingest_queue_length",
        "Samples waiting for the estimator",
        ing.queue_len as f64,
    );
    m.gauge(
        "ingest_queue_capacity",
        "Capacity of the estimator's input queue",
        ing.queue_capacity as f64,
    );
    m.counter(
        "ingest_consumed",
        "Samples the estimator took in",
        ing.consumed,
    );

    let received = m.counters("input_received", "Messages received per input");
    let accepted = m.counters("input_accepted", "Messages decoded into samples per input");
    let rejected = m.counters(
        "input_rejected",
        "Messages refused per input (malformed, out of range, bad stamp)",
    );
    let ignored = m.counters("input_ignored", "Messages deliberately not used per input");
    let dropped = m.counters(
        "input_dropped",
        "Samples dropped per input because the estimator's queue was full",
    );
    let shed = m.counters(
        "input_shed",
        "Samples shed per input for arriving far above its configured rate",
    );
    let restarts = m.counters(
        "input_clock_restarts",
        "Times an input's clock restarted and was followed",
    );
    let rate = m.gauges_unit(
        "input_rate",
        "Measured message rate per input",
        Unit::Other("hertz".into()),
    );
    let expected = m.gauges_unit(
        "input_expected_rate",
        "Configured message rate per input",
        Unit::Other("hertz".into()),
    );
    let health = m.gauges(
        "sensor_health",
        "Health state per sensor: 1 for the current state, 0 for the others",
    );
    let used = m.gauges("sensor_used", "1 if the estimator fused this sensor lately");
    let ratio = m.gauges(
        "sensor_test_ratio",
        "Innovation test ratio of the sensor's last update (> 1 rejected)",
    );
    for s in &status.sensors {
        let id = s.input.id.clone();
        let l: Labels = vec![
            ("input", id.clone()),
            ("kind", s.input.kind.as_str().to_string()),
        ];
        received.get_or_create(&l).inc_by(s.input.received);
        accepted.get_or_create(&l).inc_by(s.input.accepted);
        rejected.get_or_create(&l).inc_by(s.input.rejected);
        ignored.get_or_create(&l).inc_by(s.input.ignored);
        dropped.get_or_create(&l).inc_by(s.input.dropped);
        shed.get_or_create(&l).inc_by(s.input.shed);
        restarts.get_or_create(&l).inc_by(s.input.clock_restarts);
        rate.get_or_create(&l).set(s.input.rate_hz);
        expected.get_or_create(&l).set(s.input.expected_rate_hz);
        for st in STATES {
            health
                .get_or_create(&vec![
                    ("input", id.clone()),
                    ("state", st.as_str().to_string()),
                ])
                .set(flag(st == s.health));
        }
        let one = vec![("input", id)];
        used.get_or_create(&one).set(flag(s.used == Some(true)));
        if let Some(r) = s.test_ratio.filter(|r| r.is_finite()) {
            ratio.get_or_create(&one).set(r);
        }
    }

    let est = status.estimator.as_ref();
    m.gauge(
        "estimate_valid",
        "1 if the fused estimate is valid (what the autopilot gets)",
        flag(est.is_some_and(|e| e.valid)),
    );
    m.gauge(
        "estimate_initialised",
        "1 once the filter has started",
        flag(est.is_some_and(|e| e.initialised)),
    );
    m.gauge(
        "estimate_reset_counter",
        "The pose's reset counter (wraps at 256)",
        est.map_or(0.0, |e| f64::from(e.reset_counter)),
    );
    let std = m.gauges_unit(
        "estimate_position_std",
        "Position standard deviation per axis (ENU)",
        Unit::Meters,
    );
    if let Some(v) = est.and_then(|e| e.position_std) {
        for (axis, s) in ["x", "y", "z"].iter().zip(v) {
            std.get_or_create(&vec![("axis", axis.to_string())]).set(s);
        }
    }
    let integrity = est.map(|e| &e.integrity);
    let pl = m.gauges_unit(
        "estimate_protection_level",
        "Protection level: the integrity monitor's bound on the position error",
        Unit::Meters,
    );
    let al = m.gauges_unit(
        "estimate_alert_limit",
        "Alert limit: the largest protection level a valid pose may carry",
        Unit::Meters,
    );
    if let Some(p) = integrity.map(|i| i.protection) {
        for (direction, level, limit) in [
            ("horizontal", p.horizontal_m, p.horizontal_alert_m),
            ("vertical", p.vertical_m, p.vertical_alert_m),
        ] {
            let l = vec![("direction", direction.to_string())];
            pl.get_or_create(&l).set(level);
            al.get_or_create(&l).set(limit);
        }
    }
    m.counter(
        "integrity_exclusions",
        "Sources the integrity monitor excluded (each exclusion once)",
        integrity.map_or(0, |i| i.exclusions),
    );
    m.counter(
        "estimator_late_dropped",
        "Samples older than the estimator's history, dropped",
        est.map_or(0, |e| e.late_dropped),
    );

    let sent = m.counters(
        "output_sent",
        "Messages sent per output (MAVLink: VISION_POSITION_ESTIMATE; Zenoh: poses)",
    );
    let out_dropped = m.counters(
        "output_dropped",
        "Messages an output could not hand to its link",
    );
    let errors = m.counters("output_errors", "Send errors per output");
    let withheld = m.counters(
        "output_withheld",
        "Poses not sent to the autopilot because the estimate was invalid, stale or non-finite",
    );
    let sending = m.gauges("output_sending", "1 if the output is sending now");
    for o in &status.outputs {
        let l: Labels = vec![("output", o.name.to_string()), ("kind", o.kind.to_string())];
        sent.get_or_create(&l).inc_by(o.sent);
        out_dropped.get_or_create(&l).inc_by(o.dropped);
        errors.get_or_create(&l).inc_by(o.errors);
        if let OutputDetail::Mavlink { withheld: w, .. } = &o.detail {
            withheld.get_or_create(&l).inc_by(*w);
        }
        sending.get_or_create(&l).set(flag(o.sending));
    }
    // The autopilot's clock (MAVLink TIMESYNC).
    if let Some(ts) = status.outputs.iter().find_map(|o| match &o.detail {
        OutputDetail::Mavlink { timesync, .. } => Some(timesync),
        _ => None,
    }) {
        m.gauge(
            "mavlink_timesync_converged",
            "1 once TIMESYNC knows the autopilot's clock (poses then carry its time)",
            flag(ts.converged),
        );
        if let Some(rtt) = ts.rtt_ms {
            m.gauge(
                "mavlink_timesync_rtt_seconds",
                "Round trip of the newest TIMESYNC sample used",
                rtt / 1e3,
            );
        }
        if let Some(rate) = ts.rate {
            m.gauge(
                "mavlink_timesync_clock_rate",
                "The autopilot's clock rate against the host's (SITL --speedup N: N)",
                rate,
            );
        }
    }

    let ws = &status.websocket;
    m.gauge(
        "websocket_clients",
        "Dashboard clients connected",
        ws.clients as f64,
    );
    m.counter(
        "websocket_dropped",
        "Frames dropped for slow websocket clients (oldest first)",
        ws.dropped_total,
    );
    if let Some(r) = &status.recorder {
        m.gauge(
            "recorder_recording",
            "1 while the flight recorder writes MCAP files",
            flag(r.recording && r.error.is_none()),
        );
        m.counter(
            "recorder_messages",
            "Messages logged to the recorder's (and Foxglove's) channels",
            r.messages,
        );
        m.counter(
            "recorder_dropped",
            "Items lost to the recorder's full queue (the data path never waits)",
            r.dropped,
        );
        m.gauge(
            "recorder_bytes",
            "Bytes of the recording's files on disk",
            r.bytes as f64,
        );
        m.gauge(
            "foxglove_clients",
            "Clients of the Foxglove WebSocket server",
            r.foxglove_clients as f64,
        );
    }
    m.counter(
        "controls_refused",
        "Control requests refused for a missing or wrong token, or too many tries",
        status.controls.refused,
    );

    m.encode_with(process)
}

/// What `render_fleet` shows: plain numbers (this module does not reach into the fleet
/// view, which serves it).
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct FleetNumbers {
    pub live: usize,
    pub stale: usize,
    pub gone: usize,
    pub max_vehicles: usize,
    pub messages: u64,
    pub bytes: u64,
    pub rejected: u64,
    pub joined: u64,
    pub forgotten: u64,
    pub refused: u64,
}

/// `skyfuse monitor`'s `/metrics`: the fleet in aggregate. No family has a per-vehicle
/// label (a thousand vehicles would be a thousand series in every family, and a vehicle
/// that leaves would leave its series behind); per-vehicle state is in `/api/v1/fleet`.
/// The one label is `presence`, with its three values always present.
pub fn render_fleet(n: FleetNumbers, process: Option<ProcessStats>) -> String {
    let mut m = Metrics {
        registry: Registry::with_prefix("skyfuse_fleet"),
    };
    let vehicles = m.gauges(
        "vehicles",
        "Vehicles known to the fleet view, by presence (live, stale, gone)",
    );
    for (p, count) in [("live", n.live), ("stale", n.stale), ("gone", n.gone)] {
        vehicles
            .get_or_create(&vec![("presence", p.to_string())])
            .set(count as f64);
    }
    m.gauge(
        "vehicles_max",
        "Vehicles the view keeps at most ([fleet] max_vehicles)",
        n.max_vehicles as f64,
    );
    m.counter(
        "messages",
        "Messages received on the fleet keys",
        n.messages,
    );
    m.counter(
        "received_bytes",
        "Payload bytes received on the fleet keys",
        n.bytes,
    );
    m.counter(
        "rejected",
        "Fleet messages that could not be read",
        n.rejected,
    );
    m.counter("joined", "Vehicles that joined the view", n.joined);
    m.counter(
        "forgotten",
        "Vehicles dropped after forget_after_s gone",
        n.forgotten,
    );
    m.counter(
        "refused",
        "Vehicles not taken in (max_vehicles known, or an id too long)",
        n.refused,
    );
    m.encode_with(process)
}

impl Metrics {
    /// The registry in the text format, with the process collector's standard names
    /// (without the skyfuse prefix) where `process` is known, and one `# EOF` at the
    /// very end: the process block goes before it.
    fn encode_with(&self, process: Option<ProcessStats>) -> String {
        let mut text = String::new();
        if let Some(p) = process {
            let mut reg = Registry::default();
            let cpu: Counter<f64, AtomicU64> = Counter::default();
            cpu.inc_by(p.cpu_seconds);
            reg.register_with_unit(
                "process_cpu",
                "Total user and system CPU time",
                Unit::Seconds,
                cpu,
            );
            let rss: Gauge<f64, AtomicU64> = Gauge::default();
            rss.set(p.resident_bytes);
            reg.register_with_unit(
                "process_resident_memory",
                "Resident memory size",
                Unit::Bytes,
                rss,
            );
            let _ = encode_body(&mut text, &reg);
        }
        let mut main = String::new();
        if encode(&mut main, &self.registry).is_err() {
            return "# EOF\n".into();
        }
        match main.strip_suffix("# EOF\n") {
            Some(body) => format!("{body}{text}# EOF\n"),
            None => main,
        }
    }
}

/// A registry's families without the closing `# EOF`.
fn encode_body(out: &mut String, reg: &Registry) -> std::fmt::Result {
    let mut s = String::new();
    encode(&mut s, reg)?;
    out.push_str(s.strip_suffix("# EOF\n").unwrap_or(&s));
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_process_reads_its_own_cpu_and_memory() {
        let p = ProcessStats::read().expect("Linux /proc/self");
        assert!(p.resident_bytes > 1e6, "{p:?}");
        assert!(p.cpu_seconds >= 0.0 && p.cpu_seconds < 1e6, "{p:?}");
    }
}
