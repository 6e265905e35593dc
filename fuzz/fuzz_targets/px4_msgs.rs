#![no_main]
//! libFuzzer target: `cargo fuzz run px4_msgs` (see fuzz/Cargo.toml).

#[allow(dead_code)] // each target uses one decoder of the shared list
#[path = "../targets.rs"]
mod targets;

libfuzzer_sys::fuzz_target!(|data: &[u8]| {
    targets::Target::Px4Msgs.decode(data);
});
