//! Where tests and benches find third-party material: real flight logs and captures of
//! the real bridges live in `../shared/data` beside the project, reference tools in
//! `../shared/tools` (never committed here: the project carries only what it wrote or
//! generated). A test that needs one calls [`shared_data`] and skips, saying which test
//! and why, when it is absent.

use std::io::Write;
use std::path::{Path, PathBuf};

/// Overrides the shared folder (default `../shared` beside the project): third-party
/// data in its `data/`, the reference tools in its `tools/`.
pub const SHARED_ENV: &str = "SKYFUSE_SHARED";
/// A file to which every skipped test appends one line (`tests/run` lists it at the end).
pub const SKIP_LOG_ENV: &str = "SKYFUSE_SKIP_LOG";

/// The shared folder: `$SKYFUSE_SHARED`, else `../shared` beside the workspace root.
pub fn shared_dir() -> PathBuf {
    match std::env::var_os(SHARED_ENV) {
        Some(p) => PathBuf::from(p),
        None => PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../../shared"),
    }
}

/// `rel` under the shared folder's `data/` when it exists; otherwise `None`, after
/// saying that `test` is skipped and why (stderr, and a line in `$SKYFUSE_SKIP_LOG`).
pub fn shared_data(rel: &str, test: &str) -> Option<PathBuf> {
    find(
        &shared_dir().join("data"),
        rel,
        test,
        std::env::var_os(SKIP_LOG_ENV).map(PathBuf::from),
    )
}

fn find(dir: &Path, rel: &str, test: &str, log: Option<PathBuf>) -> Option<PathBuf> {
    let path = dir.join(rel);
    if path.exists() {
        return Some(path);
    }
    let why = format!(
        "third-party data {} is absent (it lives in ../shared beside the project, \
         or where ${SHARED_ENV} points)",
        path.display()
    );
    skipped_to(log, test, &why);
    None
}

/// Say that `test` was skipped and why: on stderr and, when `$SKYFUSE_SKIP_LOG` names a
/// file, as one line appended to it.
pub fn skipped(test: &str, why: &str) {
    skipped_to(std::env::var_os(SKIP_LOG_ENV).map(PathBuf::from), test, why);
}

fn skipped_to(log: Option<PathBuf>, test: &str, why: &str) {
    eprintln!("SKIPPED {test}: {why}");
    if let Some(log) = log {
        if let Ok(mut f) = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(log)
        {
            // One write per line: tests run in parallel and append to the same file.
            let _ = f.write_all(format!("{test}: {why}\n").as_bytes());
        }
    }
}

/// `some_or_skip!(option)`: the value, or return from the test (whatever made the
/// `None` said why it is skipped).
#[macro_export]
macro_rules! some_or_skip {
    ($e:expr) => {
        match $e {
            Some(v) => v,
            None => return,
        }
    };
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_missing_file_is_none_and_logged() {
        let log = std::env::temp_dir().join(format!("skyfuse-skip-{}.log", std::process::id()));
        let _ = std::fs::remove_file(&log);
        let dir = std::env::temp_dir();
        assert!(find(&dir, "no-such-set/none.csv", "the_test", Some(log.clone())).is_none());
        assert_eq!(
            find(&dir, "", "the_test", Some(log.clone())),
            Some(dir.join(""))
        );
        let text = std::fs::read_to_string(&log).unwrap_or_default();
        let _ = std::fs::remove_file(&log);
        assert!(text.starts_with("the_test: third-party data "), "{text}");
        assert!(text.contains("no-such-set/none.csv"), "{text}");
    }
}
