//! Heap allocations per fused sample, counted by a global allocator over the demo's
//! simulated flight (every sensor kind the estimator fuses). The filter's work per
//! sample (the IMU prediction, every measurement update) allocates nothing, as in
//! EKF2: what remains is bounded and named below.

use skyfuse_core::estimator::{rank, timing::SourceClocks, EstimatorConfig};
use skyfuse_core::fusion::{Fusion, InputSpec};
use skyfuse_core::health::HealthConfig;
use skyfuse_core::sample::Sample;
use skyfuse_core::sim::sensors::DEMO_STREAMS;
use skyfuse_core::sim::Simulator;
use std::alloc::{GlobalAlloc, Layout, System};
use std::cell::Cell;
use std::collections::BTreeMap;

/// Counts this thread's allocations (other test threads' do not count).
struct Counting;

thread_local! {
    static ALLOCATIONS: Cell<u64> = const { Cell::new(0) };
}

// SAFETY: every call is passed on to the system allocator unchanged; the count is a
// const-initialised thread-local (no allocation of its own).
unsafe impl GlobalAlloc for Counting {
    unsafe fn alloc(&self, layout: Layout) -> *mut u8 {
        ALLOCATIONS.with(|c| c.set(c.get() + 1));
        System.alloc(layout)
    }

    unsafe fn dealloc(&self, ptr: *mut u8, layout: Layout) {
        System.dealloc(ptr, layout)
    }

    unsafe fn realloc(&self, ptr: *mut u8, layout: Layout, new_size: usize) -> *mut u8 {
        ALLOCATIONS.with(|c| c.set(c.get() + 1));
        System.realloc(ptr, layout, new_size)
    }
}

#[global_allocator]
static GLOBAL: Counting = Counting;

fn allocations() -> u64 {
    ALLOCATIONS.with(Cell::get)
}

/// Per kind: each sample's allocations beyond those of copying the sample (the
/// history keeps a copy to re-run late samples from: its boxed parts, such as a ROS
/// IMU's covariances, are allocated), over the steady part (after 30 s) of 140 s of the
/// demo flight fed in the order the filter fuses them (each call fuses its own sample).
fn extra_allocations_per_kind() -> BTreeMap<&'static str, Vec<i64>> {
    let samples: Vec<Sample> = Simulator::new(DEMO_STREAMS, 1, 140.0)
        .map(|e| Sample {
            source: DEMO_STREAMS[e.stream].input_id.into(),
            stamp_us: Some((e.measured_t * 1e6) as i64),
            arrival_us: (e.publish_t * 1e6) as i64,
            data: e.data,
        })
        .collect();
    let cfg = EstimatorConfig::default();
    let mut clocks = SourceClocks::default();
    let mut order: Vec<(i64, u8, usize)> = samples
        .iter()
        .enumerate()
        .map(|(i, s)| (clocks.host_time(&cfg, s), rank(s.data.kind()), i))
        .collect();
    order.sort();
    let inputs: Vec<InputSpec> = DEMO_STREAMS
        .iter()
        .map(|s| InputSpec::new(s.input_id, s.kind, s.rate_hz))
        .collect();
    let mut fusion = Fusion::new(cfg, HealthConfig::default(), &inputs);
    let mut extra: BTreeMap<&'static str, Vec<i64>> = BTreeMap::new();
    for (t, _, i) in order {
        let s = &samples[i];
        let before = allocations();
        drop(std::hint::black_box(s.data.clone()));
        let copy = allocations() - before;
        let before = allocations();
        drop(fusion.process(s, t));
        let fused = allocations() - before;
        if t > 30_000_000 {
            let kind = s.data.kind().as_str();
            extra
                .entry(kind)
                .or_default()
                .push(fused as i64 - copy as i64);
        }
    }
    extra
}

#[test]
fn fusing_a_sample_allocates_nothing_beyond_its_copy_in_the_history() {
    let extra = extra_allocations_per_kind();
    let (mut allocating, mut total) = (0, 0);
    for kind in ["imu", "attitude", "odometry", "flow", "range", "gnss"] {
        let Some(counts) = extra.get(kind) else {
            panic!("the demo flight has no {kind} samples");
        };
        let mut sorted = counts.clone();
        sorted.sort_unstable();
        let median = sorted[sorted.len() / 2];
        let some = counts.iter().filter(|&&n| n > 0).count();
        println!(
            "{kind}: {} samples, {some} allocate beyond their copy (median {median})",
            counts.len()
        );
        // The prediction and every update allocate nothing.
        assert!(
            median <= 0,
            "{kind}: median {median} allocations beyond the copy"
        );
        allocating += some;
        total += counts.len();
    }
    // What allocates is periodic, landing on whichever sample is fused when it falls
    // due: the core's snapshot every 50 ms (to re-run late samples from: a clone of its
    // maps) and the health layer's look 10 times a second; about 46 of the demo's 535
    // samples a second.
    let share = allocating as f64 / total as f64;
    println!("{allocating} of {total} samples allocate beyond their copy");
    assert!(
        share < 0.1,
        "{:.1} % of the samples allocate",
        share * 100.0
    );
}
