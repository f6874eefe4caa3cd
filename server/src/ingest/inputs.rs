//! The `INPUT...` arguments of `build` and `--inputs LIST.txt`, expanded into the
//! list of files to read, in order (DECISIONS.md "Mosaics"): a file stays itself, a
//! directory gives its DEM files sorted by name, a glob pattern (quoted, so the shell
//! leaves it alone: `'tiles/*.hgt'`) gives its matches sorted, and a list file gives one
//! entry per line, each resolved against the list's folder and expanded the same way.

use super::DEM_EXTENSIONS;
use anyhow::{Context, bail};
use std::path::{Path, PathBuf};

/// What `build` was asked to read.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct InputSpec {
    /// `INPUT...`: files, directories, glob patterns, VRTs or `synthetic:SIZE[:SEED]`.
    pub args: Vec<String>,
    /// `--inputs LIST`: a file naming one input per line.
    pub list: Option<PathBuf>,
}

impl InputSpec {
    /// One input, as `build INPUT` had before mosaics.
    pub fn one(input: &str) -> Self {
        Self {
            args: vec![input.to_string()],
            list: None,
        }
    }
}

/// The inputs after expansion.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Expanded {
    /// `synthetic:SIZE[:SEED]`, which stands alone.
    Synthetic(String),
    /// Files (and VRTs) in order, at least one.
    Files(Vec<PathBuf>),
}

fn has_glob(s: &str) -> bool {
    s.contains(['*', '?', '['])
}

fn is_dem_file(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| DEM_EXTENSIONS.iter().any(|d| e.eq_ignore_ascii_case(d)))
}

/// Expands one entry (an argument, or a list line already joined to its folder).
fn expand_one(entry: &Path, out: &mut Vec<PathBuf>) -> anyhow::Result<()> {
    if let Some(url) = super::remote::url_of(entry) {
        out.extend(super::remote::expand(url)?);
        return Ok(());
    }
    let text = entry.to_string_lossy();
    if entry.is_dir() {
        let mut files: Vec<PathBuf> = std::fs::read_dir(entry)
            .with_context(|| format!("{}: cannot list the directory", entry.display()))?
            .map(|e| e.map(|e| e.path()))
            .collect::<Result<_, _>>()
            .with_context(|| format!("{}: cannot list the directory", entry.display()))?;
        files.retain(|p| p.is_file() && is_dem_file(p));
        if files.is_empty() {
            bail!(
                "{}: the directory holds no DEM files (.{})",
                entry.display(),
                DEM_EXTENSIONS.join(", .")
            );
        }
        files.sort();
        out.extend(files);
    } else if has_glob(&text) && !entry.exists() {
        let mut files = Vec::new();
        for m in glob::glob(&text).with_context(|| format!("{text}: not a valid glob pattern"))? {
            let p = m.with_context(|| format!("{text}: cannot read a match"))?;
            if p.is_file() {
                files.push(p);
            }
        }
        if files.is_empty() {
            bail!("{text}: no file matches this pattern");
        }
        files.sort();
        out.extend(files);
    } else {
        // A file, or a path that does not exist: opening it says which.
        out.push(entry.to_path_buf());
    }
    Ok(())
}

/// Expands `spec` into the files to read, in order.
pub fn expand(spec: &InputSpec) -> anyhow::Result<Expanded> {
    if let Some(s) = spec.args.iter().find(|a| a.starts_with("synthetic:")) {
        if spec.args.len() > 1 || spec.list.is_some() {
            bail!("{s}: a synthetic terrain cannot be combined with other inputs");
        }
        return Ok(Expanded::Synthetic(s.clone()));
    }
    let mut files = Vec::new();
    for a in &spec.args {
        expand_one(Path::new(a), &mut files)?;
    }
    if let Some(list) = &spec.list {
        let (file, _) = super::open_regular(list)
            .with_context(|| format!("{}: cannot read the input list", list.display()))?;
        let mut text = String::new();
        std::io::Read::read_to_string(&mut std::io::BufReader::new(file), &mut text)
            .with_context(|| format!("{}: cannot read the input list", list.display()))?;
        let base = list.parent().unwrap_or(Path::new(""));
        let before = files.len();
        for line in text.lines() {
            let line = line.trim();
            if line.is_empty() || line.starts_with('#') {
                continue;
            }
            let entry = Path::new(line);
            let entry = if entry.is_absolute() || super::remote::url_of(entry).is_some() {
                entry.to_path_buf()
            } else {
                // Escape the folder so that only the line's own pattern is a pattern.
                let base = if has_glob(line) {
                    PathBuf::from(glob::Pattern::escape(&base.to_string_lossy()))
                } else {
                    base.to_path_buf()
                };
                base.join(entry)
            };
            expand_one(&entry, &mut files)
                .with_context(|| format!("{}: line {line:?}", list.display()))?;
        }
        if files.len() == before {
            bail!("{}: the input list names no input", list.display());
        }
    }
    if files.is_empty() {
        bail!("no input given (name files, directories or patterns, or --inputs LIST)");
    }
    Ok(Expanded::Files(files))
}

/// A digest of which inputs `spec` names: each file's path and size, and an object's
/// ETag (from its opening, which comes first). What the parts of a distributed build
/// compare without reading a sample: each reads only its share.
pub fn identity(spec: &InputSpec) -> anyhow::Result<u64> {
    let mut h = xxhash_rust::xxh3::Xxh3::new();
    match expand(spec)? {
        Expanded::Synthetic(s) => h.update(s.as_bytes()),
        Expanded::Files(files) => {
            for f in files {
                let name = f.to_string_lossy();
                h.update(name.as_bytes());
                h.update(b"\0");
                let (size, tag) = file_identity(&f)?;
                h.update(&size.to_le_bytes());
                // An object's ETag; not a file's modification time, which differs
                // between the copies that parts on different nodes may read.
                if super::remote::url_of(&f).is_some() {
                    h.update(tag.as_bytes());
                }
                h.update(b"\0");
            }
        }
    }
    Ok(h.digest())
}

/// What identifies one input file's content without reading it: its size, and an
/// object's ETag or a file's modification time (nanoseconds since 1970).
pub fn file_identity(path: &Path) -> anyhow::Result<(u64, String)> {
    if let Some(url) = super::remote::url_of(path) {
        return Ok(super::remote::identity(url)
            .map(|(size, etag)| (size, etag.unwrap_or_default()))
            .unwrap_or_default());
    }
    let m = std::fs::metadata(path)
        .with_context(|| format!("{}: cannot read its size", path.display()))?;
    let modified = m
        .modified()
        .ok()
        .and_then(|t| t.duration_since(std::time::UNIX_EPOCH).ok())
        .map_or(0, |d| d.as_nanos());
    Ok((m.len(), format!("mtime {modified}")))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn touch(dir: &Path, names: &[&str]) {
        for n in names {
            std::fs::write(dir.join(n), b"x").unwrap();
        }
    }

    fn files(spec: &InputSpec) -> Vec<String> {
        match expand(spec).unwrap() {
            Expanded::Files(f) => f
                .iter()
                .map(|p| p.file_name().unwrap().to_string_lossy().into_owned())
                .collect(),
            Expanded::Synthetic(s) => panic!("synthetic {s}"),
        }
    }

    #[test]
    fn directories_globs_and_lists_expand_in_order() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path();
        touch(p, &["b.tif", "a.hgt", "c.TIF", "notes.txt", "all.vrt"]);
        let arg = |s: &str| p.join(s).to_string_lossy().into_owned();
        let dir = InputSpec {
            args: vec![format!("{}/", p.display())],
            list: None,
        };
        assert_eq!(files(&dir), ["a.hgt", "b.tif", "c.TIF"]);
        let glob = InputSpec {
            args: vec![arg("*.tif"), arg("a.hgt")],
            list: None,
        };
        assert_eq!(files(&glob), ["b.tif", "a.hgt"]);
        std::fs::create_dir(p.join("sub")).unwrap();
        std::fs::write(p.join("sub/list.txt"), "# tiles\n../b.tif\n\n../a.*\n").unwrap();
        let list = InputSpec {
            args: vec![arg("c.TIF")],
            list: Some(p.join("sub/list.txt")),
        };
        assert_eq!(files(&list), ["c.TIF", "b.tif", "a.hgt"]);
    }

    #[test]
    fn empty_expansions_and_mixed_synthetic_are_errors() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path();
        let err = |spec: InputSpec| format!("{:#}", expand(&spec).unwrap_err());
        let e = err(InputSpec::one(&format!("{}/*.hgt", p.display())));
        assert!(e.contains("no file matches"), "{e}");
        let e = err(InputSpec::one(&p.display().to_string()));
        assert!(e.contains("holds no DEM files"), "{e}");
        std::fs::write(p.join("list.txt"), "# nothing\n").unwrap();
        let e = err(InputSpec {
            args: vec![],
            list: Some(p.join("list.txt")),
        });
        assert!(e.contains("names no input"), "{e}");
        let e = err(InputSpec {
            args: vec!["synthetic:65".into(), "x.tif".into()],
            list: None,
        });
        assert!(e.contains("cannot be combined"), "{e}");
        // A missing plain file is passed on for opening to report.
        assert_eq!(
            expand(&InputSpec::one("/no/such.tif")).unwrap(),
            Expanded::Files(vec![PathBuf::from("/no/such.tif")])
        );
    }
}
