//! Installs the dashboard's npm dependencies (exactly as `web/package-lock.json` pins
//! them) when they are missing, so `src/http/assets.rs` can embed them and the binary
//! runs from any directory. Needs `npm` only on a machine that has not installed them.

use std::path::PathBuf;
use std::process::Command;

/// The files the binary embeds from `web/node_modules`.
const VENDOR: [&str; 2] = [
    "node_modules/uplot/dist/uPlot.iife.min.js",
    "node_modules/uplot/dist/uPlot.min.css",
];

fn main() {
    println!("cargo:rerun-if-changed=web/package-lock.json");
    println!("cargo:rerun-if-changed=web/package.json");
    let web = PathBuf::from(std::env::var_os("CARGO_MANIFEST_DIR").unwrap_or_default()).join("web");
    for f in VENDOR {
        println!("cargo:rerun-if-changed=web/{f}");
    }
    if VENDOR.iter().all(|f| web.join(f).is_file()) {
        return;
    }
    println!("cargo:warning=installing the dashboard's npm packages (npm ci in web/)");
    let status = Command::new("npm")
        .args(["ci", "--no-audit", "--no-fund", "--loglevel=error"])
        .current_dir(&web)
        .status();
    match status {
        Ok(s) if s.success() => {}
        Ok(s) => panic!("`npm ci` in {} failed ({s}); the dashboard needs its npm packages", web.display()),
        Err(e) => panic!(
            "cannot run `npm` ({e}): install Node.js and npm (Debian: `apt-get install nodejs npm`), \
             or run `npm ci` in {} yourself",
            web.display()
        ),
    }
    for f in VENDOR {
        if !web.join(f).is_file() {
            panic!("`npm ci` ran but {} is missing", web.join(f).display());
        }
    }
}
