//! The module-circle finder behind `tests/tests/module_circles.rs` (DECISIONS.md
//! "Server layout"): for every module of a crate, the graph over its child modules
//! must have no cycle. An edge `a -> b` between two children of one parent is code
//! anywhere inside `a` naming something inside `b` through a `crate::`, `super::` or
//! `self::` path (in `use` trees too, and through `pub use` re-exports). A child
//! naming its own ancestors is not an edge: that is how Rust modules use their
//! parent's items.
//!
//! The sources are read as text (comments, strings and characters blanked first),
//! which is enough for this workspace's paths; it needs no compiler. Test code
//! (`#[cfg(test)]` items and the modules they declare) can be left out: a test may
//! use any sibling it checks against without making the crate's structure circular.

use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::fmt::Write;
use std::path::{Path, PathBuf};

type Module = Vec<String>;

/// Whether `#[cfg(test)]` code counts.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum TestCode {
    /// Test code makes edges like any other code.
    Included,
    /// `#[cfg(test)]` items, and the modules they declare, are left out.
    Excluded,
}

/// Every cycle among the modules of the crate whose root (`lib.rs`, else `main.rs`)
/// is in `src`, as `parent: {members}` and one witness per edge.
///
/// # Panics
/// When `src` or a file in it cannot be read.
pub fn circles(src: &Path, test_code: TestCode) -> Vec<String> {
    let mut files: BTreeMap<Module, PathBuf> = BTreeMap::new();
    let root = if src.join("lib.rs").exists() {
        "lib"
    } else {
        "main"
    };
    collect(src, src, root, &mut files);
    let mut texts: BTreeMap<Module, String> = files
        .iter()
        .map(|(m, p)| (m.clone(), strip(&std::fs::read_to_string(p).unwrap())))
        .collect();
    if test_code == TestCode::Excluded {
        let mut test_modules = Vec::new();
        for (m, t) in &mut texts {
            for name in blank_test_items(t) {
                let mut child = m.clone();
                child.push(name);
                test_modules.push(child);
            }
        }
        let is_test = |m: &Module| test_modules.iter().any(|t| m.starts_with(t));
        files.retain(|m, _| !is_test(m));
        texts.retain(|m, _| !is_test(m));
    }
    let mut modules: BTreeSet<Module> = BTreeSet::new();
    for m in files.keys() {
        for k in 0..=m.len() {
            modules.insert(m[..k].to_vec());
        }
    }

    // Re-exports: module -> name -> the module the name comes from.
    let mut reexports: HashMap<Module, HashMap<String, Module>> = HashMap::new();
    for (m, t) in &texts {
        for at in keyword_ends(t, "use") {
            if !t[..at - 3].trim_end().ends_with(')') && !t[..at - 3].trim_end().ends_with("pub") {
                continue;
            }
            for segs in use_tree(t, at) {
                if let Some((target, rest)) = resolve_base(m, &segs, &modules)
                    && let Some(name) = rest.last()
                {
                    reexports
                        .entry(m.clone())
                        .or_default()
                        .insert(name.clone(), target);
                }
            }
        }
    }

    // Edges between siblings, with the first place each was seen.
    let mut edges: BTreeMap<Module, BTreeMap<(String, String), String>> = BTreeMap::new();
    for (m, t) in &texts {
        let mut starts: Vec<(usize, usize)> = keyword_ends(t, "use").map(|e| (e, e)).collect();
        for kw in ["crate", "super", "self"] {
            starts.extend(path_starts(t, kw).map(|s| (s, s)));
        }
        for (at, _) in starts {
            for segs in use_tree(t, at) {
                let Some((mut target, rest)) = resolve_base(m, &segs, &modules) else {
                    continue;
                };
                if let Some(next) = rest.first().and_then(|n| reexports.get(&target)?.get(n)) {
                    target = next.clone();
                }
                let common = m.iter().zip(&target).take_while(|(a, b)| a == b).count();
                if common == m.len() || common == target.len() {
                    continue; // the module itself, an ancestor or a descendant
                }
                let line = t[..at].matches('\n').count() + 1;
                let rel = files[m].strip_prefix(src).unwrap().display().to_string();
                edges
                    .entry(m[..common].to_vec())
                    .or_default()
                    .entry((m[common].clone(), target[common].clone()))
                    .or_insert_with(|| format!("{rel}:{line} -> crate::{}", target.join("::")));
            }
        }
    }

    let mut out = Vec::new();
    for (parent, e) in &edges {
        for comp in strongly_connected(e.keys()) {
            let mut text = format!(
                "{}: {{{}}}",
                std::iter::once("crate")
                    .chain(parent.iter().map(String::as_str))
                    .collect::<Vec<_>>()
                    .join("::"),
                comp.iter().cloned().collect::<Vec<_>>().join(", ")
            );
            for ((a, b), at) in e {
                if comp.contains(a) && comp.contains(b) {
                    writeln!(text).unwrap();
                    write!(text, "    {a} -> {b}: {at}").unwrap();
                }
            }
            out.push(text);
        }
    }
    out
}

/// `.rs` files under `dir` by module path (`{root}.rs` is the crate; `src/bin/`, and
/// `main.rs` beside a `lib.rs`, are other crates and skipped).
fn collect(src: &Path, dir: &Path, root: &str, out: &mut BTreeMap<Module, PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            if dir != src || path.file_name().is_none_or(|n| n != "bin") {
                collect(src, &path, root, out);
            }
            continue;
        }
        if path.extension().is_none_or(|e| e != "rs") {
            continue;
        }
        let rel = path.strip_prefix(src).unwrap().with_extension("");
        let mut parts: Module = rel
            .components()
            .map(|c| c.as_os_str().to_string_lossy().into_owned())
            .collect();
        match parts.as_slice() {
            [only] if only == root => parts.clear(),
            [only] if only == "main" || only == "lib" => continue,
            [.., last] if last == "mod" => {
                parts.pop();
            }
            _ => {}
        }
        out.insert(parts, path);
    }
}

/// `text` with comments, string and character literals blanked (lines kept).
fn strip(text: &str) -> String {
    let b = text.as_bytes();
    let mut out = b.to_vec();
    let blank = |out: &mut Vec<u8>, from: usize, to: usize| {
        for c in &mut out[from..to.min(b.len())] {
            if *c != b'\n' {
                *c = b' ';
            }
        }
    };
    let ident = |c: u8| c.is_ascii_alphanumeric() || c == b'_';
    let mut i = 0;
    while i < b.len() {
        let rest = &b[i..];
        if rest.starts_with(b"//") {
            let end = rest
                .iter()
                .position(|&c| c == b'\n')
                .map_or(b.len(), |p| i + p);
            blank(&mut out, i, end);
            i = end;
        } else if rest.starts_with(b"/*") {
            let (mut depth, mut j) = (1, i + 2);
            while j < b.len() && depth > 0 {
                if b[j..].starts_with(b"/*") {
                    depth += 1;
                    j += 2;
                } else if b[j..].starts_with(b"*/") {
                    depth -= 1;
                    j += 2;
                } else {
                    j += 1;
                }
            }
            blank(&mut out, i, j);
            i = j;
        } else if b[i] == b'r'
            && (i == 0 || !ident(b[i - 1]))
            && rest[1..]
                .iter()
                .position(|&c| c != b'#')
                .map(|p| rest[1 + p])
                == Some(b'"')
        {
            let hashes = rest[1..].iter().take_while(|&&c| c == b'#').count();
            let close: Vec<u8> = std::iter::once(b'"')
                .chain(std::iter::repeat_n(b'#', hashes))
                .collect();
            let body = i + 2 + hashes;
            let end = b[body..]
                .windows(close.len())
                .position(|w| w == close.as_slice())
                .map_or(b.len(), |p| body + p + close.len());
            blank(&mut out, i, end);
            i = end;
        } else if b[i] == b'"' {
            let mut j = i + 1;
            while j < b.len() && b[j] != b'"' {
                j += if b[j] == b'\\' { 2 } else { 1 };
            }
            blank(&mut out, i, j + 1);
            i = j + 1;
        } else if b[i] == b'\'' {
            if rest.get(1) == Some(&b'\\') {
                let end = rest[2..]
                    .iter()
                    .position(|&c| c == b'\'')
                    .map_or(b.len(), |p| i + 3 + p);
                blank(&mut out, i, end);
                i = end;
            } else if rest.get(2) == Some(&b'\'') {
                blank(&mut out, i, i + 3);
                i += 3;
            } else {
                i += 1; // a lifetime
            }
        } else {
            i += 1;
        }
    }
    String::from_utf8_lossy(&out).into_owned()
}

/// Blanks every `#[cfg(test)]` item of `t` (already [`strip`]ped): an item up to its
/// `;` or to the `}` closing its first `{`. Returns the names of the modules declared
/// `#[cfg(test)] mod name;` (their files are test code too).
fn blank_test_items(t: &mut String) -> Vec<String> {
    let mut declared = Vec::new();
    let mut b = std::mem::take(t).into_bytes();
    let mut from = 0;
    while let Some(p) = find(&b[from..], b"#[cfg(test)]") {
        let start = from + p;
        let mut i = start + b"#[cfg(test)]".len();
        // The item ends at its first `;` when that comes before any `{`, else at the
        // brace matching its first `{`.
        let mut depth = 0usize;
        let mut end = b.len();
        while i < b.len() {
            match b[i] {
                b';' if depth == 0 => {
                    end = i + 1;
                    break;
                }
                b'{' => depth += 1,
                b'}' => {
                    depth = depth.saturating_sub(1);
                    if depth == 0 {
                        end = i + 1;
                        break;
                    }
                }
                _ => {}
            }
            i += 1;
        }
        let item = String::from_utf8_lossy(&b[start..end]).into_owned();
        let words: Vec<&str> = item
            .split(|c: char| !(c.is_alphanumeric() || c == '_'))
            .filter(|w| !w.is_empty())
            .collect();
        if item.ends_with(';')
            && let Some(k) = words.iter().position(|w| *w == "mod")
            && let Some(name) = words.get(k + 1)
        {
            declared.push((*name).to_string());
        }
        for c in &mut b[start..end] {
            if *c != b'\n' {
                *c = b' ';
            }
        }
        from = end;
    }
    *t = String::from_utf8(b).unwrap_or_default();
    declared
}

fn find(hay: &[u8], needle: &[u8]) -> Option<usize> {
    hay.windows(needle.len()).position(|w| w == needle)
}

/// Where each `kw` keyword (`use`) ends.
fn keyword_ends<'a>(t: &'a str, kw: &'a str) -> impl Iterator<Item = usize> + 'a {
    t.match_indices(kw).filter_map(move |(i, _)| {
        let before = t[..i].chars().next_back();
        let after = t[i + kw.len()..].chars().next();
        let word = |c: Option<char>| c.is_some_and(|c| c.is_alphanumeric() || c == '_');
        (!word(before) && !word(after) && before != Some(':')).then_some(i + kw.len())
    })
}

/// Where each path starting with `kw::` (`crate`, `super`, `self`) starts, unless it is
/// inside a longer path or a `use` tree (which [`use_tree`] reads whole).
fn path_starts<'a>(t: &'a str, kw: &'a str) -> impl Iterator<Item = usize> + 'a {
    t.match_indices(kw).filter_map(move |(i, _)| {
        let before = t[..i].chars().next_back();
        let prev = before.is_some_and(|c| c.is_alphanumeric() || c == '_' || c == ':');
        let rest = t[i + kw.len()..].trim_start();
        (!prev && rest.starts_with("::")).then_some(i)
    })
}

/// The paths of the use tree (or plain path) at `at`, each a list of segments.
fn use_tree(t: &str, at: usize) -> Vec<Vec<String>> {
    fn tree(t: &str, pos: &mut usize, prefix: &[String], out: &mut Vec<Vec<String>>) {
        let mut segs = prefix.to_vec();
        loop {
            skip_ws(t, pos);
            let start = *pos;
            while t[*pos..]
                .chars()
                .next()
                .is_some_and(|c| c.is_alphanumeric() || c == '_')
            {
                *pos += t[*pos..].chars().next().unwrap().len_utf8();
            }
            if *pos == start {
                break;
            }
            segs.push(t[start..*pos].to_string());
            skip_ws(t, pos);
            if !t[*pos..].starts_with("::") {
                break;
            }
            *pos += 2;
            skip_ws(t, pos);
            if t[*pos..].starts_with('{') {
                *pos += 1;
                loop {
                    skip_ws(t, pos);
                    if t[*pos..].starts_with('}') || *pos >= t.len() {
                        *pos += 1;
                        return;
                    }
                    let before = *pos;
                    tree(t, pos, &segs, out);
                    skip_ws(t, pos);
                    if t[*pos..].starts_with(',') {
                        *pos += 1;
                    } else if *pos == before {
                        *pos += 1; // not a path: step over it
                    }
                }
            }
            if t[*pos..].starts_with('*') {
                break;
            }
        }
        if segs.len() > prefix.len() {
            out.push(segs);
        }
    }
    fn skip_ws(t: &str, pos: &mut usize) {
        while t[*pos..].starts_with(char::is_whitespace) {
            *pos += t[*pos..].chars().next().unwrap().len_utf8();
        }
    }
    let mut out = Vec::new();
    let mut pos = at;
    tree(t, &mut pos, &[], &mut out);
    out
}

/// The module a path leads to, and the segments past it; `None` for a path that
/// leaves the crate (another crate, `std`).
fn resolve_base(
    m: &Module,
    segs: &[String],
    modules: &BTreeSet<Module>,
) -> Option<(Module, Vec<String>)> {
    let (mut cur, mut rest) = match segs.first()?.as_str() {
        "crate" => (Vec::new(), &segs[1..]),
        "super" | "self" => {
            let mut cur = m.clone();
            let mut rest = segs;
            while let Some(first) = rest.first() {
                match first.as_str() {
                    "super" => {
                        cur.pop();
                    }
                    "self" => {}
                    _ => break,
                }
                rest = &rest[1..];
            }
            (cur, rest)
        }
        first => {
            let mut child = m.clone();
            child.push(first.to_string());
            if !modules.contains(&child) {
                return None;
            }
            (m.clone(), segs)
        }
    };
    while let Some(first) = rest.first() {
        let mut next = cur.clone();
        next.push(first.clone());
        if !modules.contains(&next) {
            break;
        }
        cur = next;
        rest = &rest[1..];
    }
    Some((cur, rest.to_vec()))
}

/// Tarjan's strongly connected components of two or more nodes.
fn strongly_connected<'a>(
    edges: impl Iterator<Item = &'a (String, String)>,
) -> Vec<BTreeSet<String>> {
    struct State<'a> {
        adj: BTreeMap<&'a str, Vec<&'a str>>,
        index: HashMap<&'a str, usize>,
        low: HashMap<&'a str, usize>,
        stack: Vec<&'a str>,
        out: Vec<BTreeSet<String>>,
    }
    fn visit<'a>(s: &mut State<'a>, v: &'a str) {
        let n = s.index.len();
        s.index.insert(v, n);
        s.low.insert(v, n);
        s.stack.push(v);
        for w in s.adj[v].clone() {
            if !s.index.contains_key(w) {
                visit(s, w);
                let lw = s.low[w];
                let lv = s.low.get_mut(v).unwrap();
                *lv = (*lv).min(lw);
            } else if s.stack.contains(&w) {
                let iw = s.index[w];
                let lv = s.low.get_mut(v).unwrap();
                *lv = (*lv).min(iw);
            }
        }
        if s.low[v] == s.index[v] {
            let mut comp = BTreeSet::new();
            while let Some(w) = s.stack.pop() {
                comp.insert(w.to_string());
                if w == v {
                    break;
                }
            }
            if comp.len() > 1 {
                s.out.push(comp);
            }
        }
    }
    let mut adj: BTreeMap<&str, Vec<&str>> = BTreeMap::new();
    for (a, b) in edges {
        adj.entry(a).or_default().push(b);
        adj.entry(b).or_default();
    }
    let nodes: Vec<&str> = adj.keys().copied().collect();
    let mut s = State {
        adj,
        index: HashMap::new(),
        low: HashMap::new(),
        stack: Vec::new(),
        out: Vec::new(),
    };
    for v in nodes {
        if !s.index.contains_key(v) {
            visit(&mut s, v);
        }
    }
    s.out
}
