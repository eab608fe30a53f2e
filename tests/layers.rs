//! The layers follow the data (issue 19): numbers at the bottom, then the IR, the
//! frontends that produce it, the machine and motion models, the passes that use them and
//! the backends that print it. This test reads every file under `src/` and fails on a
//! `crate::…` reference that runs against that order, and on a circle of imports between
//! files.
//!
//! Unit tests count too: a test that needs a higher layer lives in `tests/`. Doc comments
//! count as well (a doc link to a higher layer ties the documentation to it); plain
//! comments are left out.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

/// Each top-level module and the modules it may use. Anything not listed here
/// (`lib.rs`, `main.rs`) may use everything.
const LAYERS: &[(&str, &[&str])] = &[
    ("num", &[]),
    ("ir", &["num"]),
    ("diag", &["ir", "num"]),
    ("valid", &["ir", "num", "diag"]),
    ("heightmap", &["ir", "num", "diag"]),
    ("front", &["ir", "num", "diag"]),
    ("back", &["ir", "num", "diag"]),
    ("machine", &["ir", "num", "diag"]),
    ("motion", &["ir", "num", "diag", "machine"]),
    ("readback", &["ir", "num", "diag", "machine", "motion"]),
    (
        "passes",
        &[
            "ir",
            "num",
            "diag",
            "valid",
            "machine",
            "motion",
            "heightmap",
        ],
    ),
    (
        "preset",
        &[
            "ir",
            "num",
            "diag",
            "valid",
            "heightmap",
            "front",
            "back",
            "machine",
            "motion",
            "passes",
            "readback",
        ],
    ),
    (
        "pipeline",
        &[
            "ir",
            "num",
            "diag",
            "valid",
            "heightmap",
            "front",
            "back",
            "machine",
            "motion",
            "passes",
            "readback",
            "preset",
        ],
    ),
    (
        "plot",
        &[
            "ir",
            "num",
            "diag",
            "valid",
            "heightmap",
            "front",
            "back",
            "machine",
            "motion",
            "passes",
            "readback",
            "preset",
            "pipeline",
        ],
    ),
];

fn src() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("src")
}

/// A file's path as the repository names it (`src/passes/ik.rs`).
fn shown(file: &Path) -> String {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    file.strip_prefix(root)
        .unwrap_or(file)
        .display()
        .to_string()
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(entries) = std::fs::read_dir(dir) else {
        return;
    };
    for e in entries.flatten() {
        let p = e.path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

/// The module path of a file: `src/passes/ik.rs` is `["passes", "ik"]`, a `mod.rs` is its
/// folder's module, `lib.rs` and `main.rs` the crate root.
fn module_of(file: &Path) -> Vec<String> {
    let rel = file.strip_prefix(src()).unwrap_or(file);
    let mut parts: Vec<String> = rel
        .iter()
        .map(|s| s.to_string_lossy().into_owned())
        .collect();
    if let Some(last) = parts.pop() {
        let stem = last.trim_end_matches(".rs");
        if !matches!(stem, "mod" | "lib" | "main") {
            parts.push(stem.to_string());
        }
    }
    parts
}

/// The code of a file without its plain comments. Doc comments stay: a doc link to a
/// higher layer makes the documentation depend on it, and a reader of the lower layer
/// should not need the higher one. Test modules count: a unit test that needs a higher
/// layer belongs in `tests/`.
fn code_of(text: &str) -> String {
    let mut out = String::new();
    for line in text.lines() {
        let code = match line.find("//") {
            Some(i) if line[i..].starts_with("///") || line[i..].starts_with("//!") => line,
            Some(i) if !line[..i].contains('"') => &line[..i],
            _ => line,
        };
        out.push_str(code);
        out.push('\n');
    }
    out
}

/// Every module path a file's code names: `crate::a::b::C` as `["a", "b", "C"]`, each
/// name of `crate::{a::x, b}`, and `super::…` resolved against the file's module.
fn references(module: &[String], code: &str) -> Vec<Vec<String>> {
    let mut refs = Vec::new();
    let bytes = code.as_bytes();
    let ident = |b: u8| b.is_ascii_alphanumeric() || b == b'_';
    let mut i = 0;
    while i < bytes.len() {
        let Some(rest) = code.get(i..) else {
            i += 1;
            continue;
        };
        let (base, skip) = if rest.starts_with("crate::") && (i == 0 || !ident(bytes[i - 1])) {
            (Vec::new(), "crate::".len())
        } else if rest.starts_with("super::") && (i == 0 || !ident(bytes[i - 1])) {
            // `super` is the module's parent, whether the module is a folder or a file.
            let mut j = i;
            let mut ups = 0;
            while code[j..].starts_with("super::") {
                ups += 1;
                j += "super::".len();
            }
            let m = module[..module.len().saturating_sub(ups)].to_vec();
            (m, j - i)
        } else {
            i += 1;
            continue;
        };
        let start = i + skip;
        let mut paths = Vec::new();
        read_tree(&code[start..], base, &mut paths);
        refs.extend(paths);
        i = start;
    }
    refs
}

/// Reads `a::b::{c, d::e}` (a path, possibly a group) into full paths.
fn read_tree(text: &str, prefix: Vec<String>, out: &mut Vec<Vec<String>>) {
    let mut path = prefix;
    let mut rest = text;
    loop {
        let len = rest
            .find(|c: char| !(c.is_ascii_alphanumeric() || c == '_'))
            .unwrap_or(rest.len());
        if len == 0 {
            if let Some(group) = rest.strip_prefix('{') {
                let end = matching_brace(group);
                for item in split_top(&group[..end]) {
                    read_tree(item.trim(), path.clone(), out);
                }
            } else {
                out.push(path);
            }
            return;
        }
        path.push(rest[..len].to_string());
        rest = &rest[len..];
        match rest.strip_prefix("::") {
            Some(r) => rest = r,
            None => {
                out.push(path);
                return;
            }
        }
    }
}

fn matching_brace(s: &str) -> usize {
    let mut depth = 1;
    for (i, c) in s.char_indices() {
        match c {
            '{' => depth += 1,
            '}' => {
                depth -= 1;
                if depth == 0 {
                    return i;
                }
            }
            _ => {}
        }
    }
    s.len()
}

fn split_top(s: &str) -> Vec<&str> {
    let (mut parts, mut depth, mut start) = (Vec::new(), 0, 0);
    for (i, c) in s.char_indices() {
        match c {
            '{' => depth += 1,
            '}' => depth -= 1,
            ',' if depth == 0 => {
                parts.push(&s[start..i]);
                start = i + 1;
            }
            _ => {}
        }
    }
    parts.push(&s[start..]);
    parts
}

struct Crate {
    /// Module path of each file.
    files: BTreeMap<Vec<String>, PathBuf>,
    /// What each file's code names.
    refs: BTreeMap<Vec<String>, Vec<Vec<String>>>,
}

fn read_crate() -> Crate {
    let mut paths = Vec::new();
    rust_files(&src(), &mut paths);
    let mut files = BTreeMap::new();
    let mut refs = BTreeMap::new();
    for p in paths {
        let module = module_of(&p);
        let text = std::fs::read_to_string(&p).unwrap_or_default();
        refs.insert(module.clone(), references(&module, &code_of(&text)));
        files.insert(module, p);
    }
    Crate { files, refs }
}

/// The file a path names: its longest prefix that is a module with a file.
fn file_of<'a>(files: &'a BTreeMap<Vec<String>, PathBuf>, path: &[String]) -> Option<&'a [String]> {
    (1..=path.len())
        .rev()
        .find_map(|n| files.get_key_value(&path[..n]).map(|(k, _)| k.as_slice()))
}

#[test]
fn no_module_uses_a_layer_above_it() {
    let krate = read_crate();
    let layers: BTreeMap<&str, &[&str]> = LAYERS.iter().copied().collect();
    let mut wrong = BTreeSet::new();
    for (module, refs) in &krate.refs {
        let Some(top) = module.first() else { continue };
        let Some(allowed) = layers.get(top.as_str()) else {
            continue;
        };
        for r in refs {
            let Some(target) = r.first() else { continue };
            if target == top || !layers.contains_key(target.as_str()) {
                continue;
            }
            if !allowed.contains(&target.as_str()) {
                wrong.insert(format!(
                    "{} uses crate::{}",
                    shown(&krate.files[module]),
                    r.join("::")
                ));
            }
        }
    }
    assert!(
        wrong.is_empty(),
        "imports against the layers (see LAYERS in tests/layers.rs):\n{}",
        wrong.into_iter().collect::<Vec<_>>().join("\n")
    );
}

#[test]
fn no_files_import_each_other_in_a_circle() {
    let krate = read_crate();
    // File → files it names, leaving out a module file naming its own submodules (that
    // is where they are declared, not a use of them).
    let mut edges: BTreeMap<&[String], BTreeSet<&[String]>> = BTreeMap::new();
    for (module, refs) in &krate.refs {
        for r in refs {
            let Some(to) = file_of(&krate.files, r) else {
                continue;
            };
            if to != module.as_slice() && !to.starts_with(module) {
                edges.entry(module).or_default().insert(to);
            }
        }
    }
    let circles = strongly_connected(&edges);
    let described: Vec<String> = circles
        .iter()
        .map(|c| {
            c.iter()
                .map(|m| shown(&krate.files[*m]))
                .collect::<Vec<_>>()
                .join(" <-> ")
        })
        .collect();
    assert!(
        described.is_empty(),
        "files that import each other in a circle:\n{}",
        described.join("\n")
    );
}

/// The strongly connected components of more than one file (Tarjan).
fn strongly_connected<'a>(
    edges: &BTreeMap<&'a [String], BTreeSet<&'a [String]>>,
) -> Vec<Vec<&'a [String]>> {
    struct State<'a> {
        index: BTreeMap<&'a [String], usize>,
        low: BTreeMap<&'a [String], usize>,
        stack: Vec<&'a [String]>,
        on_stack: BTreeSet<&'a [String]>,
        out: Vec<Vec<&'a [String]>>,
    }
    fn visit<'a>(
        v: &'a [String],
        edges: &BTreeMap<&'a [String], BTreeSet<&'a [String]>>,
        s: &mut State<'a>,
    ) {
        let i = s.index.len();
        s.index.insert(v, i);
        s.low.insert(v, i);
        s.stack.push(v);
        s.on_stack.insert(v);
        for &w in edges.get(v).into_iter().flatten() {
            if !s.index.contains_key(w) {
                visit(w, edges, s);
                let lw = s.low[w];
                let lv = s.low[v];
                s.low.insert(v, lv.min(lw));
            } else if s.on_stack.contains(w) {
                let iw = s.index[w];
                let lv = s.low[v];
                s.low.insert(v, lv.min(iw));
            }
        }
        if s.low[v] == s.index[v] {
            let mut component = Vec::new();
            while let Some(w) = s.stack.pop() {
                s.on_stack.remove(w);
                component.push(w);
                if w == v {
                    break;
                }
            }
            if component.len() > 1 {
                s.out.push(component);
            }
        }
    }
    let mut s = State {
        index: BTreeMap::new(),
        low: BTreeMap::new(),
        stack: Vec::new(),
        on_stack: BTreeSet::new(),
        out: Vec::new(),
    };
    for &v in edges.keys() {
        if !s.index.contains_key(v) {
            visit(v, edges, &mut s);
        }
    }
    s.out
}

#[test]
fn the_reader_sees_the_imports_it_must() {
    let code = code_of(
        "use crate::{ir::Block, back::Decimals};\n// crate::plot in a comment\nfn f() { crate::motion::x(); }\n",
    );
    let refs = references(&["passes".into(), "ik".into()], &code);
    let names: Vec<String> = refs.iter().map(|r| r.join("::")).collect();
    assert_eq!(names, ["ir::Block", "back::Decimals", "motion::x"]);
    let sup = references(
        &["front".into(), "cl".into(), "arc".into()],
        "use super::lower::Circle;",
    );
    assert_eq!(
        sup,
        [vec![
            "front".to_string(),
            "cl".into(),
            "lower".into(),
            "Circle".into()
        ]]
    );
    let sup = references(&["front".into(), "cl".into()], "use super::Frontend;");
    assert_eq!(sup, [vec!["front".to_string(), "Frontend".into()]]);
}
