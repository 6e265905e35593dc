//! The import graph: which top-level module of each crate uses which, read from the
//! sources (`use crate::x`, `crate::x::` paths). Dependencies must point one way: no
//! two modules of a crate reach each other, directly or around a cycle, and the core
//! crate names no transport (zenoh, tokio, axum). `cargo test --test structure --
//! --nocapture` prints the graph.

mod common;
use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

type Graph = BTreeMap<String, BTreeSet<String>>;

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(rd) = std::fs::read_dir(dir) else {
        return;
    };
    let mut entries: Vec<PathBuf> = rd.filter_map(|e| e.ok().map(|e| e.path())).collect();
    entries.sort();
    for p in entries {
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|e| e == "rs") {
            out.push(p);
        }
    }
}

/// The top-level module a file of `src` belongs to (`estimator/flow.rs` → `estimator`).
fn module_of(src: &Path, file: &Path) -> Option<String> {
    let rel = file.strip_prefix(src).ok()?;
    let first = rel.components().next()?.as_os_str().to_str()?;
    let name = first.strip_suffix(".rs").unwrap_or(first);
    (!matches!(name, "lib" | "main")).then(|| name.to_string())
}

/// Code without comments (line comments and doc comments), so prose naming a module is
/// not an import.
fn code_of(text: &str) -> String {
    text.lines()
        .map(|l| match l.find("//") {
            Some(i) => &l[..i],
            None => l,
        })
        .collect::<Vec<_>>()
        .join("\n")
}

/// Names `crate::NAME` reaches in `code`, including `use crate::{a, b::c}` groups.
fn crate_refs(code: &str) -> BTreeSet<String> {
    let mut out = BTreeSet::new();
    let mut rest = code;
    while let Some(i) = rest.find("crate::") {
        rest = &rest[i + "crate::".len()..];
        if let Some(group) = rest.strip_prefix('{') {
            let end = group.find('}').unwrap_or(group.len());
            for part in group[..end].split(',') {
                let name: String = part
                    .trim()
                    .chars()
                    .take_while(|c| c.is_alphanumeric() || *c == '_')
                    .collect();
                if !name.is_empty() {
                    out.insert(name);
                }
            }
        } else {
            let name: String = rest
                .chars()
                .take_while(|c| c.is_alphanumeric() || *c == '_')
                .collect();
            if !name.is_empty() {
                out.insert(name);
            }
        }
    }
    out
}

fn graph(src: &Path) -> Graph {
    let mut files = vec![];
    rust_files(src, &mut files);
    let modules: BTreeSet<String> = files.iter().filter_map(|f| module_of(src, f)).collect();
    let mut g = Graph::new();
    for f in &files {
        let Some(from) = module_of(src, f) else {
            continue;
        };
        if f.file_name().is_some_and(|n| n == "tests.rs") {
            continue;
        }
        let text = std::fs::read_to_string(f).unwrap_or_default();
        // Unit tests may reach anywhere; the graph is of the code that ships.
        let shipped = text.split("#[cfg(test)]").next().unwrap_or("");
        let deps = g.entry(from.clone()).or_default();
        for to in crate_refs(&code_of(shipped)) {
            if to != from && modules.contains(&to) {
                deps.insert(to);
            }
        }
    }
    g
}

/// Strongly connected components with more than one module: the cycles.
fn cycles(g: &Graph) -> Vec<BTreeSet<String>> {
    let reach = |from: &str| -> BTreeSet<String> {
        let mut seen = BTreeSet::new();
        let mut stack = vec![from.to_string()];
        while let Some(m) = stack.pop() {
            for d in g.get(&m).into_iter().flatten() {
                if seen.insert(d.clone()) {
                    stack.push(d.clone());
                }
            }
        }
        seen
    };
    let mut found: Vec<BTreeSet<String>> = vec![];
    for m in g.keys() {
        let r = reach(m);
        if !r.contains(m) {
            continue;
        }
        let scc: BTreeSet<String> = r.iter().filter(|o| reach(o).contains(m)).cloned().collect();
        if !found.contains(&scc) {
            found.push(scc);
        }
    }
    found
}

fn print(name: &str, g: &Graph) {
    println!("{name}:");
    for (m, deps) in g {
        let d: Vec<&str> = deps.iter().map(String::as_str).collect();
        println!("  {m} -> {}", d.join(", "));
    }
}

#[test]
fn imports_point_one_way_in_both_crates() {
    let root = common::repo_root();
    for (name, src) in [
        ("skyfuse-core", root.join("crates/skyfuse-core/src")),
        ("skyfuse (service)", root.join("src")),
    ] {
        let g = graph(&src);
        print(name, &g);
        assert!(g.len() >= 8, "{name}: only {} modules found", g.len());
        let c = cycles(&g);
        assert!(c.is_empty(), "{name}: modules that reach each other: {c:?}");
    }
}

#[test]
fn the_core_crate_names_no_transport() {
    let root = common::repo_root();
    let mut files = vec![];
    rust_files(&root.join("crates/skyfuse-core/src"), &mut files);
    for f in files {
        let code = code_of(&std::fs::read_to_string(&f).unwrap_or_default());
        for word in ["zenoh::", "tokio::", "axum::"] {
            assert!(!code.contains(word), "{} uses {word}", f.display());
        }
    }
    let manifest =
        std::fs::read_to_string(root.join("crates/skyfuse-core/Cargo.toml")).unwrap_or_default();
    for dep in ["zenoh", "tokio", "axum"] {
        assert!(
            !manifest.lines().any(|l| l.trim_start().starts_with(dep)),
            "skyfuse-core depends on {dep}"
        );
    }
}

#[test]
fn the_graph_reader_sees_a_cycle() {
    // The check above could pass by reading nothing: a made-up cycle must be caught.
    let mut g = Graph::new();
    g.entry("a".into()).or_default().insert("b".into());
    g.entry("b".into()).or_default().insert("c".into());
    g.entry("c".into()).or_default().insert("a".into());
    g.entry("d".into()).or_default().insert("a".into());
    assert_eq!(cycles(&g).len(), 1);
    let refs = crate_refs("use crate::{estimator::Event, health};\nlet x = crate::sync::lock(&m);");
    assert_eq!(
        refs.into_iter().collect::<Vec<_>>(),
        ["estimator", "health", "sync"]
    );
}

#[test]
fn the_container_build_stubs_every_bench_target() {
    // docker/Dockerfile builds the dependencies against stub targets; a [[bench]] it
    // does not stub makes the manifest unreadable there (found when fuzz was added).
    let root = common::repo_root();
    let manifest = std::fs::read_to_string(root.join("Cargo.toml")).unwrap_or_default();
    let dockerfile = std::fs::read_to_string(root.join("docker/Dockerfile")).unwrap_or_default();
    let stubs = dockerfile
        .lines()
        .find(|l| l.contains("for b in") && l.contains("benches/$b.rs"))
        .unwrap_or_else(|| panic!("no bench stub loop in docker/Dockerfile"));
    let mut benches = 0;
    for block in manifest.split("[[bench]]").skip(1) {
        let name = block
            .lines()
            .find_map(|l| l.trim().strip_prefix("name = "))
            .map(|n| n.trim_matches('"'))
            .unwrap_or_else(|| panic!("a [[bench]] without a name"));
        benches += 1;
        assert!(
            stubs
                .split_whitespace()
                .any(|w| w.trim_end_matches(';') == name),
            "docker/Dockerfile does not stub bench {name}: {stubs}"
        );
    }
    assert!(benches >= 3, "{benches} benches found");
}
