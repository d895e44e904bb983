//! The module stack of `docs/architecture.md`, enforced: every top-level module of `src/`
//! imports only modules below it in [`STACK`] (never one above, never in a circle), and `unsafe`
//! appears in `src/os` only. The checker reads the sources (comments and string literals left
//! out) and follows `crate::` paths, `use crate::{...}` groups and `super::` chains that climb
//! to the crate root; the tests below it show that it catches what it must.

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};

/// The stack, bottom first: a module may import those before it.
const STACK: [&str; 12] = [
    "os", "error", "progress", "output", "geom", "rays", "mesh", "physical", "mapping", "pack",
    "logical", "render",
];

/// The files of `logical`, bottom first: each may import those before it. The walks (`trace`)
/// know neither the stream that parks them nor the scene that runs them.
const LOGICAL: [&str; 15] = [
    "held",
    "top_bounds",
    "pager",
    "trace",
    "stream",
    "order",
    "batch",
    "chunked",
    "report",
    "verify",
    "scene",
    "hits",
    "nearest",
    "frame",
    "run",
];

/// The modules of the comparison crate (`crates/oavm-compare`), by level, bottom first: a module
/// imports only modules of lower levels. The structures of the comparison are peers (none
/// builds on another), the benchmark runs them all, the shadow-ray variants use the benchmark's
/// scenes.
const COMPARE: [&[&str]; 5] = [
    &["counters", "leaf"],
    &["aabb", "test_util"],
    &["grid", "kdtree", "octree", "bvh", "oavm_accel"],
    &["bench"],
    &["shadow"],
];

/// The module that may hold `unsafe` code (`#![deny(unsafe_code)]` elsewhere).
const UNSAFE_HOME: &str = "os";

fn src() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("src")
}

/// Every `.rs` file under `dir`.
fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).expect("read src") {
        let p = e.expect("entry").path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// The sources of the comparison crate (research code apart from the library).
fn compare_src() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("crates/oavm-compare/src")
}

/// The module path of a file under `root`: `a/b.rs` and `a/b/mod.rs` are `[a, b]`.
fn module_path(root: &Path, file: &Path) -> Vec<String> {
    let rel = file.strip_prefix(root).expect("under the sources");
    let mut parts: Vec<String> = rel
        .iter()
        .map(|c| c.to_string_lossy().into_owned())
        .collect();
    let last = parts.pop().expect("a file name");
    if last != "mod.rs" && last != "lib.rs" {
        parts.push(last.trim_end_matches(".rs").to_string());
    }
    parts
}

/// `text` with comments, string and character literals blanked out (so a doc link or a message
/// naming a module is not an import).
fn code_only(text: &str) -> String {
    let b = text.as_bytes();
    let mut out = String::with_capacity(text.len());
    let mut i = 0;
    while i < b.len() {
        if b[i..].starts_with(b"//") {
            while i < b.len() && b[i] != b'\n' {
                i += 1;
            }
        } else if b[i..].starts_with(b"/*") {
            let mut depth = 0;
            while i < b.len() {
                if b[i..].starts_with(b"/*") {
                    depth += 1;
                    i += 2;
                } else if b[i..].starts_with(b"*/") {
                    depth -= 1;
                    i += 2;
                    if depth == 0 {
                        break;
                    }
                } else {
                    i += 1;
                }
            }
        } else if b[i] == b'r' && (b[i..].starts_with(b"r\"") || b[i..].starts_with(b"r#")) {
            // A raw string: r"...", r#"..."#.
            let mut j = i + 1;
            let mut hashes = 0;
            while j < b.len() && b[j] == b'#' {
                hashes += 1;
                j += 1;
            }
            if j < b.len() && b[j] == b'"' {
                let close: Vec<u8> = std::iter::once(b'"')
                    .chain(std::iter::repeat_n(b'#', hashes))
                    .collect();
                j += 1;
                while j < b.len() && !b[j..].starts_with(&close) {
                    j += 1;
                }
                i = j + close.len();
                out.push_str("\"\"");
            } else {
                out.push('r');
                i += 1;
            }
        } else if b[i] == b'"' {
            i += 1;
            while i < b.len() && b[i] != b'"' {
                i += if b[i] == b'\\' { 2 } else { 1 };
            }
            i += 1;
            out.push_str("\"\"");
        } else if b[i] == b'\'' && i + 2 < b.len() && (b[i + 2] == b'\'' || b[i + 1] == b'\\') {
            // A character literal ('x', '\n'), not a lifetime.
            i += 1;
            while i < b.len() && b[i] != b'\'' {
                i += if b[i] == b'\\' { 2 } else { 1 };
            }
            i += 1;
            out.push_str("' '");
        } else {
            out.push(b[i] as char);
            i += 1;
        }
    }
    out
}

/// The top-level modules that code in module `path` (a module path under `src/`) names: through
/// `crate::x`, `crate::{x, y::z}` and `super::` chains that reach the crate root.
fn imports(path: &[String], code: &str) -> BTreeSet<String> {
    imports_under(path, code, &[])
}

/// The children of module `under` that code in module `path` names: through `crate::` paths and
/// `super::` chains that resolve to `under::x` (groups `{a, b::c}` expanded at any depth).
/// Names inside `path`'s own child of `under` are not imports of another child.
fn imports_under(path: &[String], code: &str, under: &[&str]) -> BTreeSet<String> {
    let mut found = BTreeSet::new();
    let tokens: Vec<&str> = code
        .split(|c: char| {
            !(c.is_alphanumeric() || c == '_' || c == ':' || c == '{' || c == '}' || c == ',')
        })
        .filter(|t| !t.is_empty())
        .collect();
    let joined = tokens.join(" ");
    let bytes = joined.as_bytes();
    let mut i = 0;
    while i < joined.len() {
        let rest = &joined[i..];
        let at_word = i == 0 || !(bytes[i - 1].is_ascii_alphanumeric() || bytes[i - 1] == b'_');
        let (base, after): (Vec<String>, &str) = if at_word && rest.starts_with("crate::") {
            (Vec::new(), &rest["crate::".len()..])
        } else if at_word && rest.starts_with("super::") {
            let mut n = 0;
            let mut r = rest;
            while r.starts_with("super::") {
                n += 1;
                r = &r["super::".len()..];
            }
            // `n` supers from module `path` name its ancestor `path[..len - n]` (the root when
            // n >= len).
            (path[..path.len().saturating_sub(n)].to_vec(), r)
        } else {
            i += rest.chars().next().map_or(1, char::len_utf8);
            continue;
        };
        i += rest.len() - after.len();
        for tail in expand(after) {
            let full: Vec<&str> = base
                .iter()
                .map(String::as_str)
                .chain(tail.iter().map(String::as_str))
                .collect();
            if full.len() > under.len() && full[..under.len()] == *under {
                found.insert(full[under.len()].to_string());
            }
        }
    }
    // A module's own child of `under` is not an import of another.
    if path.len() > under.len() && path[..under.len()].iter().zip(under).all(|(a, b)| a == b) {
        found.remove(&path[under.len()]);
    }
    found
}

/// The paths a use-path beginning at `rest` names, its `{...}` groups expanded: `a::b::{c,
/// d::e}` gives `[a, b, c]` and `[a, b, d, e]`; the last segment may be an item, not a module.
fn expand(rest: &str) -> Vec<Vec<String>> {
    let ident = |s: &str| -> String {
        s.chars()
            .take_while(|c| c.is_alphanumeric() || *c == '_')
            .collect()
    };
    let mut prefix = Vec::new();
    let mut r = rest.trim_start();
    loop {
        if let Some(group) = r.strip_prefix('{') {
            // Split the group at its top-level commas.
            let mut out = Vec::new();
            let (mut depth, mut start) = (1, 0);
            for (j, c) in group.char_indices() {
                match c {
                    '{' => depth += 1,
                    '}' | ',' if depth == 1 => {
                        for t in expand(&group[start..j]) {
                            out.push(prefix.iter().cloned().chain(t).collect());
                        }
                        start = j + 1;
                        if c == '}' {
                            return out;
                        }
                    }
                    '}' => depth -= 1,
                    _ => {}
                }
            }
            return out;
        }
        let name = ident(r);
        if name.is_empty() {
            return if prefix.is_empty() {
                Vec::new()
            } else {
                vec![prefix]
            };
        }
        r = &r[name.len()..];
        prefix.push(name);
        match r.strip_prefix("::") {
            Some(more) => r = more.trim_start(),
            None => return vec![prefix],
        }
    }
}

/// Imports against the stack: `(file, module, imported)` for each import of a module that is
/// not below the file's module.
fn violations(files: &[(Vec<String>, String, String)]) -> Vec<(String, String, String)> {
    let rank = |m: &str| STACK.iter().position(|s| *s == m);
    let mut bad = Vec::new();
    for (path, file, code) in files {
        let Some(top) = path.first() else { continue };
        let Some(me) = rank(top) else { continue };
        for name in imports(path, code) {
            // Names that are not modules of the stack (`crate::Error`, re-exports at the root)
            // are checked where they are defined.
            if let Some(them) = rank(&name)
                && them > me
            {
                bad.push((file.clone(), top.clone(), name));
            }
        }
    }
    bad
}

fn sources() -> Vec<(Vec<String>, String, String)> {
    sources_in(&src())
}

/// `(module path, file, code)` of every file of a crate's sources but its binaries.
fn sources_in(root: &Path) -> Vec<(Vec<String>, String, String)> {
    let mut files = Vec::new();
    rust_files(root, &mut files);
    files.sort();
    files
        .into_iter()
        .filter(|f| !f.starts_with(root.join("bin")))
        .map(|f| {
            let code = code_only(&std::fs::read_to_string(&f).expect("read"));
            let name = f.strip_prefix(root).unwrap().to_string_lossy().into_owned();
            (module_path(root, &f), name, code)
        })
        .collect()
}

#[test]
fn every_module_imports_only_modules_below_it() {
    let files = sources();
    // Every top-level module of the crate is in the stack (a new one must be placed).
    let tops: BTreeSet<String> = files
        .iter()
        .filter_map(|(p, ..)| p.first().cloned())
        .collect();
    let unplaced: Vec<&String> = tops
        .iter()
        .filter(|t| !STACK.contains(&t.as_str()))
        .collect();
    assert!(
        unplaced.is_empty(),
        "modules not in the stack of docs/architecture.md: {unplaced:?}"
    );
    let bad = violations(&files);
    assert!(
        bad.is_empty(),
        "imports of modules above in the stack ({}):\n{}",
        STACK.join(" < "),
        bad.iter()
            .map(|(f, m, n)| format!("  {f}: {m} imports {n}"))
            .collect::<Vec<_>>()
            .join("\n")
    );
}

/// Imports between the files of `logical` against [`LOGICAL`]: `(file, module, imported)`.
fn logical_violations(files: &[(Vec<String>, String, String)]) -> Vec<(String, String, String)> {
    let rank = |m: &str| LOGICAL.iter().position(|s| *s == m);
    let mut bad = Vec::new();
    for (path, file, code) in files {
        if path.first().map(String::as_str) != Some("logical") || path.len() < 2 {
            continue;
        }
        let me = &path[1];
        for name in imports_under(path, code, &["logical"]) {
            match (rank(me), rank(&name)) {
                (Some(a), Some(b)) if b < a => {}
                // Names that are not files of `logical` (its re-exports) are checked where
                // they are defined.
                (_, None) => {}
                _ => bad.push((file.clone(), me.clone(), name)),
            }
        }
    }
    bad
}

#[test]
fn the_files_of_logical_import_only_those_below_them() {
    let files = sources();
    let children: BTreeSet<String> = files
        .iter()
        .filter(|(p, ..)| p.first().map(String::as_str) == Some("logical") && p.len() >= 2)
        .map(|(p, ..)| p[1].clone())
        .collect();
    let unplaced: Vec<&String> = children
        .iter()
        .filter(|c| !LOGICAL.contains(&c.as_str()))
        .collect();
    assert!(
        unplaced.is_empty(),
        "files of logical not in its stack: {unplaced:?}"
    );
    let bad = logical_violations(&files);
    assert!(
        bad.is_empty(),
        "imports of logical's files above them ({}):\n{}",
        LOGICAL.join(" < "),
        bad.iter()
            .map(|(f, m, n)| format!("  {f}: {m} imports {n}"))
            .collect::<Vec<_>>()
            .join("\n")
    );
}

#[test]
fn unsafe_code_lives_in_one_module() {
    let lib = std::fs::read_to_string(src().join("lib.rs")).unwrap();
    assert!(
        lib.contains("#![deny(unsafe_code)]"),
        "lib.rs must deny unsafe code"
    );
    let mut files = Vec::new();
    rust_files(&src(), &mut files);
    let mut found = Vec::new();
    for f in files {
        let code = code_only(&std::fs::read_to_string(&f).unwrap());
        let words = code.split(|c: char| !(c.is_alphanumeric() || c == '_'));
        if words.into_iter().any(|w| w == "unsafe") {
            found.push(f.strip_prefix(src()).unwrap().to_path_buf());
        }
    }
    assert!(
        !found.is_empty(),
        "the os module has unsafe code: the check must see it"
    );
    assert!(
        found.iter().all(|f| f.starts_with(UNSAFE_HOME)),
        "unsafe outside src/{UNSAFE_HOME}: {found:?}"
    );
    // Every unsafe block (and impl) says why it is sound.
    for f in &found {
        let text = std::fs::read_to_string(src().join(f)).unwrap();
        let lines: Vec<&str> = text.lines().collect();
        for (i, l) in lines.iter().enumerate() {
            let code = code_only(l);
            let has = code
                .split(|c: char| !(c.is_alphanumeric() || c == '_'))
                .any(|w| w == "unsafe");
            if !has || code.contains("unsafe_code") || code.trim_start().starts_with("#[") {
                continue;
            }
            let before = lines[i.saturating_sub(8)..i].join("\n");
            assert!(
                before.contains("SAFETY:") || l.contains("SAFETY:"),
                "{}:{}: unsafe without a SAFETY comment above it",
                f.display(),
                i + 1
            );
        }
    }
}

// The checker itself: it must see what it is for.

fn file(path: &str, code: &str) -> (Vec<String>, String, String) {
    let p: Vec<String> = path.split('/').map(str::to_string).collect();
    (p, path.to_string(), code_only(code))
}

#[test]
fn the_checker_catches_upward_imports_in_every_form() {
    let cases = [
        file("physical/file", "use crate::logical::Scene;"),
        file(
            "physical/file",
            "use crate::{error::Error, mapping::TreeMap};",
        ),
        file("geom/ray", "fn f() { let _ = crate::mesh::load(p); }"),
        file("physical/block", "use super::super::pack::blocks;"),
        file("physical", "use super::pack::x;"),
        file(
            "mapping/rank",
            "use crate::{\n    physical::format,\n    logical::Order,\n};",
        ),
    ];
    for c in &cases {
        assert_eq!(violations(std::slice::from_ref(c)).len(), 1, "{}", c.2);
    }
    let fine = [
        file(
            "logical/scene",
            "use crate::physical::format::Header; use crate::Error;",
        ),
        file(
            "physical/file",
            "// use crate::logical::Scene;\nlet s = \"crate::logical\";",
        ),
        file("physical/file", "/* crate::pack */ use super::format::*;"),
        file("pack/blocks", "use super::super::physical::format;"),
        file("physical/block", "use super::file::OavmFile;"),
    ];
    for c in &fine {
        assert!(violations(std::slice::from_ref(c)).is_empty(), "{}", c.2);
    }
}

#[test]
fn the_checker_catches_circles_inside_logical() {
    let cases = [
        file("logical/trace", "use super::scene::Walk;"),
        file("logical/trace/neighbours", "use super::super::stream::Job;"),
        file("logical/trace/topdown", "use crate::logical::scene::Scene;"),
        file("logical/pager", "use super::{held::ReadyMap, trace::Tree};"),
        file("logical/held", "fn f() { crate::logical::{order::Order}; }"),
    ];
    for c in &cases {
        assert_eq!(
            logical_violations(std::slice::from_ref(c)).len(),
            1,
            "{}",
            c.2
        );
    }
    let fine = [
        file("logical/stream", "use super::trace::{Best, Entry};"),
        file(
            "logical/trace/ray",
            "use super::{HitInfo, Tree}; use super::super::held::Held;",
        ),
        file("logical/trace/cluster", "use super::ray::RayCtx;"),
        file(
            "logical/scene",
            "use crate::logical::pager::Pager; use crate::physical::Header;",
        ),
        file(
            "logical/pager/tests",
            "use super::*; use super::super::held::ReadyMap;",
        ),
    ];
    for c in &fine {
        assert!(
            logical_violations(std::slice::from_ref(c)).is_empty(),
            "{}",
            c.2
        );
    }
}

/// Imports of the comparison crate's modules against [`COMPARE`]: `(file, module, imported)`.
fn compare_violations(files: &[(Vec<String>, String, String)]) -> Vec<(String, String, String)> {
    let level = |m: &str| COMPARE.iter().position(|l| l.contains(&m));
    let mut bad = Vec::new();
    for (path, file, code) in files {
        let Some(top) = path.first() else { continue };
        for name in imports(path, code) {
            match (level(top), level(&name)) {
                (Some(a), Some(b)) if b < a => {}
                (_, None) => {} // an item of the crate's root (the Accelerator trait, re-exports)
                _ if name == *top => {}
                _ => bad.push((file.clone(), top.clone(), name)),
            }
        }
    }
    bad
}

/// Research code apart from the product: the library names nothing of the comparison crate
/// (nor depends on it), the comparison crate reaches the library only through its public API
/// (the compiler sees to that), has no `unsafe` code, and its own modules keep to [`COMPARE`].
#[test]
fn the_comparison_crate_stands_apart_and_keeps_its_own_stack() {
    let manifest =
        std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/Cargo.toml")).unwrap();
    let deps = manifest
        .split("\n[")
        .filter(|t| t.contains("dependencies]"))
        .collect::<Vec<_>>()
        .join("\n");
    assert!(
        !deps.contains("oavm-compare"),
        "oavm depends on the comparison crate"
    );
    for (_, file, code) in sources() {
        assert!(
            !code.contains("oavm_compare"),
            "src/{file} names the comparison crate"
        );
    }
    let files = sources_in(&compare_src());
    assert!(
        files.len() > 20,
        "the comparison crate's sources: {} files",
        files.len()
    );
    let tops: BTreeSet<String> = files
        .iter()
        .filter_map(|(p, ..)| p.first().cloned())
        .collect();
    let unplaced: Vec<&String> = tops
        .iter()
        .filter(|t| !COMPARE.iter().any(|l| l.contains(&t.as_str())))
        .collect();
    assert!(
        unplaced.is_empty(),
        "modules of oavm-compare not in its stack: {unplaced:?}"
    );
    let bad = compare_violations(&files);
    assert!(
        bad.is_empty(),
        "imports against oavm-compare's stack:\n{}",
        bad.iter()
            .map(|(f, m, n)| format!("  {f}: {m} imports {n}"))
            .collect::<Vec<_>>()
            .join("\n")
    );
    for (_, file, code) in &files {
        let unsafe_word = code
            .split(|c: char| !(c.is_alphanumeric() || c == '_'))
            .any(|w| w == "unsafe");
        assert!(
            !unsafe_word,
            "crates/oavm-compare/src/{file} has unsafe code"
        );
    }
}

#[test]
fn the_checker_catches_structures_leaning_on_each_other() {
    let cases = [
        file("grid/build", "use crate::kdtree::KdTree;"),
        file("kdtree/shadow", "use super::super::bench::BenchScene;"),
        file("leaf", "use crate::{Counters, aabb::Aabb};"),
        file("bench", "use crate::shadow::run;"),
    ];
    for c in &cases {
        assert_eq!(
            compare_violations(std::slice::from_ref(c)).len(),
            1,
            "{}",
            c.2
        );
    }
    let fine = [
        file(
            "grid/build",
            "use crate::aabb::Aabb; use crate::leaf::Tri; use super::node;",
        ),
        file(
            "shadow",
            "use super::bench::BenchScene; use super::{Accelerator, OavmAccel};",
        ),
        file("bench", "use crate::bvh::Bvh; use crate::test_util::rays;"),
    ];
    for c in &fine {
        assert!(
            compare_violations(std::slice::from_ref(c)).is_empty(),
            "{}",
            c.2
        );
    }
}
