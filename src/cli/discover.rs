//! `skyfuse discover`: listen on the Zenoh network for a while, print what is published
//! and what skyfuse makes of it, and write a starting config.

use super::NetArgs;
use crate::config::{Config, ZenohMode};
use crate::discovery::{self, Discovered, Discovery};
use crate::ingest::zenoh_in;
use std::io::Write;
use std::path::PathBuf;
use std::sync::Arc;

pub async fn discover(
    mut config: Config,
    net: &NetArgs,
    seconds: f64,
    write: Option<PathBuf>,
    json: bool,
) -> Result<(), String> {
    if !(seconds.is_finite() && seconds > 0.0 && seconds <= 3600.0) {
        return Err(format!("--seconds {seconds}: between 0 and 3600"));
    }
    // A listener on the service's port would collide with the service being watched.
    if net.listen.is_empty() {
        config.zenoh.listen.clear();
    }
    let session = zenoh_in::open_session(&config.zenoh)
        .await
        .map_err(|e| e.to_string())?;
    let table = Arc::new(Discovery::default());
    let topics = crate::ros_graph::TopicTable::default();
    let ros_watch = crate::ros_graph::discover(&session, topics.clone()).await;
    let watch = discovery::watch(&session, table.clone())
        .await
        .ok_or("cannot subscribe to every key (see the log)")?;
    listen_for(seconds).await;
    let found = table.snapshot(
        crate::clock::now_us(),
        &config.inputs,
        &discovery::announced(&topics),
        &[],
    );
    let _ = watch.undeclare().await;
    if let Some(w) = ros_watch {
        let _ = w.undeclare().await;
    }
    let _ = session.close().await;

    let mut out = std::io::stdout().lock();
    // A closed pipe (`| head`) ends the listing, not the program with a panic.
    let text = if json {
        serde_json::to_string_pretty(&found).map_err(|e| e.to_string())? + "\n"
    } else {
        table_text(&found)
    };
    let _ = out.write_all(text.as_bytes());
    if let Some(path) = write {
        let proposed = discovery::propose(&found);
        let mut zenoh = Vec::new();
        if !config.zenoh.connect.is_empty() {
            let mode = match config.zenoh.mode {
                ZenohMode::Peer => "peer",
                ZenohMode::Client => "client",
            };
            zenoh.push(format!("mode = {mode:?}"));
            zenoh.push(format!("connect = {:?}", config.zenoh.connect));
        }
        let header = format!(
            "Written by `skyfuse discover` (skyfuse {}): {} keys seen in {seconds} s, {} read as inputs below.",
            env!("CARGO_PKG_VERSION"),
            found.keys.len(),
            proposed.len()
        );
        let text = discovery::starting_config(&proposed, &zenoh, &header);
        // What is written must be what `run` takes.
        if !proposed.is_empty() {
            Config::from_toml_str(&text, &path.display().to_string())
                .map_err(|e| format!("the config written would not load (a bug): {e}"))?;
        }
        std::fs::write(&path, &text).map_err(|e| format!("{}: {e}", path.display()))?;
        let _ = writeln!(
            out,
            "\nwrote {}: {} input{} (skyfuse check-config {0}; skyfuse run -c {0})",
            path.display(),
            proposed.len(),
            if proposed.len() == 1 { "" } else { "s" }
        );
    }
    Ok(())
}

/// Wait `seconds`, with a countdown on a terminal (a person waits here).
async fn listen_for(seconds: f64) {
    use std::io::IsTerminal;
    let tty = std::io::stderr().is_terminal();
    let end = tokio::time::Instant::now() + std::time::Duration::from_secs_f64(seconds);
    if !tty {
        eprintln!("listening on Zenoh for {seconds} s");
        tokio::time::sleep_until(end).await;
        return;
    }
    loop {
        let left = end.saturating_duration_since(tokio::time::Instant::now());
        if left.is_zero() {
            break;
        }
        let done = 1.0 - left.as_secs_f64() / seconds;
        let bar = (done * 30.0).round() as usize;
        eprint!(
            "\rlistening on Zenoh [{}{}] {:4.1} s left ",
            "#".repeat(bar),
            " ".repeat(30 - bar.min(30)),
            left.as_secs_f64()
        );
        tokio::time::sleep(left.min(std::time::Duration::from_millis(200))).await;
    }
    eprintln!("\rlistening on Zenoh: done{}", " ".repeat(40));
}

/// The table as text: one line per key.
fn table_text(d: &Discovered) -> String {
    use std::fmt::Write as _;
    let mut s = String::new();
    let w = d
        .keys
        .iter()
        .map(|k| k.key.len())
        .max()
        .unwrap_or(3)
        .clamp(3, 48);
    let _ = writeln!(s, "{:<w$}  {:>8}  {:<46}  INPUT", "KEY", "RATE", "WHAT");
    for k in &d.keys {
        let rate = match k.last_age_ms {
            Some(_) => format!("{:.1} Hz", k.mean_rate_hz),
            None => "-".into(),
        };
        let what = match (k.format, &k.ros_type, &k.message) {
            (_, Some(t), _) => format!(
                "{} {t}{}",
                k.format.unwrap_or(crate::codec::Format::Ros2),
                if k.type_from == Some("announced") {
                    " (bridge)"
                } else {
                    ""
                }
            ),
            (Some(f), None, Some(m)) => format!("{f} {m}"),
            (Some(f), None, None) if !k.candidates.is_empty() => {
                format!("{f}: one of {}", k.candidates.join(", "))
            }
            (Some(f), None, None) => f.to_string(),
            (None, None, _) => "not read by skyfuse".into(),
        };
        let what = if k.kinds.is_empty() {
            what
        } else {
            let kinds: Vec<&str> = k.kinds.iter().map(|k| k.as_str()).collect();
            format!("{what} ({})", kinds.join("+"))
        };
        let input = if k.own_output {
            "(this service's output)".to_string()
        } else if !k.read_by.is_empty() {
            k.read_by.join(", ")
        } else if let Some(n) = &k.near {
            format!("unused; looks meant for {}: {}", n.input, n.why)
        } else {
            "unused".into()
        };
        let _ = writeln!(s, "{:<w$}  {rate:>8}  {what:<46}  {input}", k.key);
    }
    if d.overflow > 0 {
        let _ = writeln!(
            s,
            "(and {} messages on more keys than the {} listed)",
            d.overflow,
            discovery::MAX_KEYS
        );
    }
    if d.keys.is_empty() {
        let _ = writeln!(
            s,
            "(nothing published: is this on the same Zenoh network? --connect tcp/HOST:7447)"
        );
    }
    s
}
