//! The architecture invariants of ARCHITECTURE.md that the dependency graph
//! can show, read from `cargo metadata` (the real resolve of the workspace,
//! normal dependencies only: dev- and build-dependencies do not ship):
//!
//! - the pure domain crates reach no adapter crate of the workspace (files,
//!   network, serial, model folders, binaries), however indirectly, and
//!   neither they nor a workspace crate they reach depends on an external
//!   crate that does I/O at the edges (async runtime, serial ports, Modbus,
//!   signals, DICOM networking, memory maps, compression) or that belongs to
//!   a command line (argument parsing, `anyhow`, log subscribers). What an
//!   external library uses inside itself (tract's `anyhow`) is its own
//!   business;
//! - the one exception is named: `dbt-pipeline` runs a loaded DBToR model,
//!   so it links `dbt-dbtor`, whose `load` reads a model folder; the
//!   pipeline itself reads no file (its callers load the model), and
//!   `dbt-dbtor` is held to the same external rules as the pure crates.

use serde_json::Value;
use std::collections::{BTreeMap, BTreeSet};
use std::process::Command;

/// The pure domain crates (ARCHITECTURE.md, "(pure)").
const PURE: &[&str] = &[
    "dbt-geometry",
    "dbt-projector",
    "dbt-cone",
    "dbt-materials",
    "dbt-phantom",
    "dbt-forward",
    "dbt-recon",
    "dbt-metrics",
    "dbt-dose",
    "dbt-scatter",
    "dbt-tissue",
    "dbt-physics-density",
    "dbt-intervals",
    "dbt-gantry",
    "dbt-dicom",
    "dbt-intake",
    "dbt-pipeline",
    "dbt-conv",
    "dbt-isa",
    "dbt-status",
];

/// Workspace crates at the edges: adapters and binaries.
const ADAPTERS: &[&str] = &[
    "dbt-store",
    "dbt-pacs",
    "dbt-model",
    "dbtor-firmware",
    "host-sim",
    "dbt-eval",
    "dbt-bench",
    "dbt-dose-cli",
    "dbt-cli",
    "hil-tests",
];

/// External crates that do I/O at the edges or serve a command line.
const EDGE_CRATES: &[&str] = &[
    "tokio",
    "tokio-serial",
    "tokio-modbus",
    "serialport",
    "signal-hook",
    "dicom-ul",
    "memmap2",
    "flate2",
    "clap",
    "anyhow",
    "tracing-subscriber",
    "tiny_http",
    "indicatif",
];

/// The standard output of `cargo ARGS` run in the workspace's root, which
/// must succeed.
fn cargo(args: &[&str]) -> String {
    let out = Command::new(env!("CARGO"))
        .args(args)
        .current_dir(concat!(env!("CARGO_MANIFEST_DIR"), "/.."))
        .output()
        .expect("cargo runs");
    assert!(
        out.status.success(),
        "cargo {}: {}",
        args.join(" "),
        String::from_utf8_lossy(&out.stderr)
    );
    String::from_utf8_lossy(&out.stdout).into_owned()
}

/// `cargo metadata` of the workspace (format 1, locked, offline) with
/// `extra` options.
fn cargo_metadata(extra: &[&str]) -> Value {
    let args = ["metadata", "--format-version", "1", "--locked", "--offline"];
    serde_json::from_str(&cargo(&[&args[..], extra].concat())).unwrap()
}

/// Package name by package id, and each package's normal dependencies (ids).
/// (On this machine's platform: the other platforms' dependencies are not
/// downloaded.)
fn graph() -> (BTreeMap<String, String>, BTreeMap<String, Vec<String>>) {
    let rustc = Command::new("rustc")
        .arg("-vV")
        .output()
        .expect("rustc runs");
    let host = String::from_utf8_lossy(&rustc.stdout)
        .lines()
        .find_map(|l| l.strip_prefix("host: ").map(str::to_string))
        .expect("rustc -vV names the host");
    let m = cargo_metadata(&["--filter-platform", &host]);
    let names = m["packages"]
        .as_array()
        .unwrap()
        .iter()
        .map(|p| {
            (
                p["id"].as_str().unwrap().to_string(),
                p["name"].as_str().unwrap().to_string(),
            )
        })
        .collect();
    let deps = m["resolve"]["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|n| {
            let normal = n["deps"]
                .as_array()
                .unwrap()
                .iter()
                .filter(|d| {
                    d["dep_kinds"]
                        .as_array()
                        .unwrap()
                        .iter()
                        .any(|k| k["kind"].is_null())
                })
                .map(|d| d["pkg"].as_str().unwrap().to_string())
                .collect();
            (n["id"].as_str().unwrap().to_string(), normal)
        })
        .collect();
    (names, deps)
}

/// Every package `id` depends on, however indirectly, with the chain that
/// reaches it (ids, from `id`'s direct dependency on); with `workspace_only`
/// the search goes on only through workspace crates (a dependency of an
/// external crate is not followed).
fn closure(
    id: &str,
    deps: &BTreeMap<String, Vec<String>>,
    workspace_only: bool,
) -> BTreeMap<String, Vec<String>> {
    let mut seen: BTreeMap<String, Vec<String>> = BTreeMap::new();
    let mut stack: Vec<(String, Vec<String>)> = vec![(id.to_string(), vec![])];
    while let Some((p, path)) = stack.pop() {
        if workspace_only && !p.starts_with("path+file://") {
            continue;
        }
        for d in deps.get(&p).into_iter().flatten() {
            if !seen.contains_key(d) {
                let mut chain = path.clone();
                chain.push(d.clone());
                seen.insert(d.clone(), chain.clone());
                stack.push((d.clone(), chain));
            }
        }
    }
    seen
}

#[test]
fn pure_crates_reach_no_adapter_and_no_edge_crate() {
    let (names, deps) = graph();
    let id_of = |name: &str| -> String {
        names
            .iter()
            .find(|(_, n)| n.as_str() == name)
            .map(|(id, _)| id.clone())
            .unwrap_or_else(|| panic!("{name} is not in the workspace's metadata"))
    };
    // Every workspace crate is classified (a new one must be placed).
    let members: BTreeSet<String> = names
        .iter()
        .filter(|(id, _)| id.starts_with("path+file://"))
        .map(|(_, n)| n.clone())
        .collect();
    // workspace-hack has no code: it only unifies features (its test below).
    let classified: BTreeSet<String> = PURE
        .iter()
        .chain(ADAPTERS)
        .chain(["dbt-dbtor", "workspace-hack"].iter())
        .map(|s| s.to_string())
        .collect();
    assert_eq!(
        members, classified,
        "every workspace crate is pure, an adapter, dbt-dbtor or workspace-hack (hil-tests/tests/architecture.rs)"
    );

    let mut violations = Vec::new();
    for &krate in PURE.iter().chain(["dbt-dbtor"].iter()) {
        for (dep, chain) in closure(&id_of(krate), &deps, true) {
            let name = &names[&dep];
            let chain: Vec<&str> = chain.iter().map(|c| names[c].as_str()).collect();
            let forbidden = ADAPTERS.contains(&name.as_str())
                || EDGE_CRATES.contains(&name.as_str())
                || (PURE.contains(&krate)
                    && name == "dbt-dbtor"
                    && krate != "dbt-pipeline"
                    && !chain.contains(&"dbt-pipeline"));
            if forbidden {
                violations.push(format!("{krate} -> {}", chain.join(" -> ")));
            }
        }
    }
    assert!(
        violations.is_empty(),
        "pure crates reaching adapters or edge crates:\n{}",
        violations.join("\n")
    );
}

/// The test can fail: the binaries do reach the edge crates it looks for.
#[test]
fn the_edges_are_where_the_test_looks_for_them() {
    let (names, deps) = graph();
    let id = names
        .iter()
        .find(|(_, n)| n.as_str() == "dbtor-firmware")
        .map(|(id, _)| id.clone())
        .unwrap();
    let reached: BTreeSet<&str> = closure(&id, &deps, true)
        .keys()
        .map(|d| names[d].as_str())
        .collect();
    for edge in ["tokio", "serialport", "clap", "dbt-store", "dbt-pacs"] {
        assert!(reached.contains(edge), "the firmware reaches {edge}");
    }
}

/// A crate's top-level modules (each `src/NAME.rs` and `src/NAME/`, their
/// submodules folded in; `lib.rs`, `main.rs` and `bin/` aside) and, for
/// each, the other top-level modules its code names as `crate::OTHER`
/// (comments and the trailing `#[cfg(test)] mod tests` left out).
fn module_imports(src: &std::path::Path) -> BTreeMap<String, BTreeSet<String>> {
    fn rs_files(dir: &std::path::Path, out: &mut Vec<std::path::PathBuf>) {
        for e in std::fs::read_dir(dir).unwrap().flatten() {
            let p = e.path();
            if p.is_dir() {
                rs_files(&p, out);
            } else if p.extension().is_some_and(|x| x == "rs") {
                out.push(p);
            }
        }
    }
    let mut files: BTreeMap<String, Vec<std::path::PathBuf>> = BTreeMap::new();
    for e in std::fs::read_dir(src).unwrap().flatten() {
        let p = e.path();
        let name = p.file_stem().unwrap().to_string_lossy().to_string();
        if p.is_dir() {
            if name != "bin" {
                rs_files(&p, files.entry(name).or_default());
            }
        } else if p.extension().is_some_and(|x| x == "rs") && name != "lib" && name != "main" {
            files.entry(name).or_default().push(p);
        }
    }
    let modules: BTreeSet<String> = files.keys().cloned().collect();
    files
        .iter()
        .map(|(m, fs)| {
            let mut used = BTreeSet::new();
            for f in fs {
                let text = std::fs::read_to_string(f).unwrap();
                let text = text
                    .find("#[cfg(test)]\nmod tests")
                    .map_or(text.as_str(), |i| &text[..i]);
                for line in text.lines() {
                    let code = line.split("//").next().unwrap_or("");
                    for (i, _) in code.match_indices("crate::") {
                        let name: String = code[i + 7..]
                            .chars()
                            .take_while(|c| c.is_alphanumeric() || *c == '_')
                            .collect();
                        if name != *m && modules.contains(&name) {
                            used.insert(name);
                        }
                    }
                }
            }
            (m.clone(), used)
        })
        .collect()
}

/// A cycle of `g`, if it has one (the modules in order, the first again at
/// the end).
fn find_cycle(g: &BTreeMap<String, BTreeSet<String>>) -> Option<Vec<String>> {
    fn visit(
        g: &BTreeMap<String, BTreeSet<String>>,
        m: &str,
        path: &mut Vec<String>,
        done: &mut BTreeSet<String>,
    ) -> Option<Vec<String>> {
        if let Some(i) = path.iter().position(|p| p == m) {
            let mut c = path[i..].to_vec();
            c.push(m.to_string());
            return Some(c);
        }
        if done.contains(m) {
            return None;
        }
        path.push(m.to_string());
        for n in g.get(m).into_iter().flatten() {
            if let Some(c) = visit(g, n, path, done) {
                return Some(c);
            }
        }
        path.pop();
        done.insert(m.to_string());
        None
    }
    let mut done = BTreeSet::new();
    g.keys()
        .find_map(|m| visit(g, m, &mut Vec::new(), &mut done))
}

/// No circle of imports among a crate's modules, in any workspace crate
/// (issue #50): each module can be read after the ones it uses. (The
/// crates' own graph cannot have one: cargo refuses it.)
#[test]
fn no_crate_has_a_circle_of_module_imports() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let manifest = std::fs::read_to_string(root.join("Cargo.toml")).unwrap();
    let ws: toml::Value = toml::from_str(&manifest).unwrap();
    let members = ws["workspace"]["members"].as_array().unwrap();
    assert!(members.len() > 20, "{members:?}");
    let mut circles = Vec::new();
    for m in members {
        let src = root.join(m.as_str().unwrap()).join("src");
        if !src.is_dir() {
            continue;
        }
        if let Some(c) = find_cycle(&module_imports(&src)) {
            circles.push(format!("{}: {}", m.as_str().unwrap(), c.join(" -> ")));
        }
    }
    assert!(
        circles.is_empty(),
        "circles of module imports:\n{}",
        circles.join("\n")
    );
    // The search finds one where there is one.
    let g: BTreeMap<String, BTreeSet<String>> = [
        ("a", &["b"][..]),
        ("b", &["c"][..]),
        ("c", &["a"][..]),
        ("d", &[][..]),
    ]
    .into_iter()
    .map(|(m, n)| (m.to_string(), n.iter().map(|s| s.to_string()).collect()))
    .collect();
    assert_eq!(find_cycle(&g).map(|c| c.len()), Some(4));
}

/// Where a pipeline stage reads the header's cone-beam system (the field,
/// not a [`dbt_intake::ConeHeader`]'s `system()`): `.system` followed by
/// neither `(` nor a further identifier character.
fn field_reads_of_system(code: &str) -> usize {
    code.match_indices(".system")
        .filter(|(i, m)| {
            let next = code[i + m.len()..].chars().next();
            !matches!(next, Some(c) if c == '(' || c == '_' || c.is_alphanumeric())
        })
        .count()
}

/// Issue #50 point 2: cone-beam frames and slice sinograms are two types
/// (`dbt_intake::layout`), the layout is asked once (`into_layout`, in
/// `process_with_progress`), and no stage of the pipeline reads the
/// header's `system` to find out which it holds. The DICOM mapping
/// (`dicom_input.rs`) writes and reads the file form of both layouts and
/// is exempt; tests are not stages.
#[test]
fn no_stage_of_the_pipeline_asks_for_the_layout() {
    let src = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../crates/dbt-pipeline/src");
    let (mut reads, mut asks) = (Vec::new(), Vec::new());
    let mut files = 0;
    for e in std::fs::read_dir(&src).unwrap() {
        let p = e.unwrap().path();
        let name = p.file_name().unwrap().to_string_lossy().into_owned();
        if !name.ends_with(".rs") || name == "dicom_input.rs" {
            continue;
        }
        files += 1;
        let text = std::fs::read_to_string(&p).unwrap();
        let code = text.split("#[cfg(test)]").next().unwrap_or_default();
        let code: String = code
            .lines()
            .filter(|l| !l.trim_start().starts_with("//"))
            .collect::<Vec<_>>()
            .join("\n");
        let n = field_reads_of_system(&code);
        if n > 0 {
            reads.push(format!("{name}: {n}"));
        }
        for _ in code.matches("into_layout(") {
            asks.push(name.clone());
        }
    }
    assert!(files >= 10, "{files} stage files in {}", src.display());
    assert!(
        reads.is_empty(),
        "stages reading the header's cone-beam system: {reads:?}"
    );
    assert_eq!(asks, ["process.rs"], "where the layout is asked");
    // The search finds what it looks for.
    assert_eq!(
        field_reads_of_system("match &h.system { } h.system() s.system_name x.system;"),
        2
    );
}

/// Each crate's features in the workspace's resolve, as `cargo tree` prints
/// them: `name version` -> the feature list, for the normal and build
/// dependencies and, with `dev`, the tests' dev-dependencies too.
fn features(dev: bool) -> BTreeMap<String, String> {
    let edges = if dev {
        "normal,build,dev"
    } else {
        "normal,build"
    };
    cargo(&[
        "tree",
        "--workspace",
        "--locked",
        "--prefix",
        "none",
        "-e",
        edges,
        "-f",
        "{p}|{f}",
    ])
    .lines()
    .filter_map(|l| {
        let (p, f) = l.trim_end_matches(" (*)").split_once('|')?;
        // `name vX.Y.Z (path)` -> `name vX.Y.Z`
        let p: Vec<&str> = p.split_whitespace().take(2).collect();
        Some((p.join(" "), f.to_string()))
    })
    .collect()
}

/// The binaries (`cargo build --workspace --bins`, what `scripts/test-all.sh`
/// builds once for the process tests) and the tests (`cargo test
/// --workspace`) compile every crate they share with the same features, so
/// that cargo builds it once for both (issue #52 point 7). A dev-dependency
/// that turns on more features of a shared crate breaks this: give
/// `crates/workspace-hack` that crate with those features.
#[test]
fn build_and_test_features_agree() {
    let build = features(false);
    let test = features(true);
    assert!(
        build.keys().any(|k| k.starts_with("tract-core ")),
        "cargo tree's output not understood: {:?}",
        build.keys().take(5).collect::<Vec<_>>()
    );
    let differ: Vec<String> = build
        .iter()
        .filter_map(|(p, f)| {
            let t = test.get(p)?;
            (t != f).then(|| format!("{p}: binaries [{f}], tests [{t}]"))
        })
        .collect();
    assert!(
        differ.is_empty(),
        "crates built with other features for the tests than for the binaries \
         (add them to crates/workspace-hack/Cargo.toml):\n{}",
        differ.join("\n")
    );
}

/// Every file of a workspace crate's `tests/` folder is compiled: a test
/// target of its own, or a module (`#[path = "FILE.rs"] mod STEM;`) of one
/// of the crate's test targets, as where several files share one test
/// binary (`autotests = false`: CI's time, issue #52 point 7). Otherwise
/// cargo would never build a file left out, and its tests would silently
/// never run.
#[test]
fn every_file_in_tests_is_built() {
    let m = cargo_metadata(&["--no-deps"]);
    let mut left_out = Vec::new();
    let mut merged = 0;
    for p in m["packages"].as_array().unwrap() {
        let manifest = std::path::Path::new(p["manifest_path"].as_str().unwrap());
        let dir = manifest.parent().unwrap().join("tests");
        let Ok(entries) = std::fs::read_dir(&dir) else {
            continue;
        };
        let roots: Vec<std::path::PathBuf> = p["targets"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|t| t["kind"].as_array().unwrap().iter().any(|k| k == "test"))
            .map(|t| std::path::PathBuf::from(t["src_path"].as_str().unwrap()))
            .collect();
        let root_texts: Vec<String> = roots
            .iter()
            .map(|r| std::fs::read_to_string(r).unwrap())
            .collect();
        for e in entries {
            let path = e.unwrap().path();
            let (Some(name), Some("rs")) = (
                path.file_name().and_then(|n| n.to_str()),
                path.extension().and_then(|x| x.to_str()),
            ) else {
                continue;
            };
            if roots.contains(&path) {
                continue;
            }
            let stem = name.trim_end_matches(".rs");
            let decl = format!("#[path = \"{name}\"]\nmod {stem};");
            if root_texts.iter().any(|t| t.contains(&decl)) {
                merged += 1;
            } else {
                left_out.push(path.display().to_string());
            }
        }
    }
    assert!(
        left_out.is_empty(),
        "files in a tests/ folder that no test target builds (declare them as modules of the crate's test binary): {left_out:?}"
    );
    assert!(
        merged > 0,
        "no test file is a module of a merged test binary"
    );
}
