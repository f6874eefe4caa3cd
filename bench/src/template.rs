//! `{{name}}` placeholders in the BENCHMARKS.md template.
//!
//! The template holds the prose (methods, what the seeds report); the numbers come
//! only from the results. Both directions are checked so nothing is silently lost:
//! a placeholder the report does not know is an error (a typo would otherwise
//! leave `{{buidl}}` in the document), and so is a section the template has no
//! place for (its tables would otherwise vanish).

use anyhow::{Context, bail};
use std::collections::{BTreeMap, BTreeSet};

/// Replaces every `{{name}}` in `template` with `values[name]`.
///
/// Errors name the line: an unknown name, an unclosed `{{`, a name that is not
/// `[a-z_]+`. A name in `values` that the template never uses is an error too.
/// Replacement text is inserted as is (never scanned for placeholders itself).
pub fn render(template: &str, values: &BTreeMap<&str, String>) -> anyhow::Result<String> {
    let mut out =
        String::with_capacity(template.len() + values.values().map(String::len).sum::<usize>());
    let mut used = BTreeSet::new();
    let mut rest = template;
    while let Some(start) = rest.find("{{") {
        let line = line_of(template, template.len() - rest.len() + start);
        out.push_str(&rest[..start]);
        let after = &rest[start + 2..];
        let end = after
            .find("}}")
            .with_context(|| format!("line {line}: `{{{{` is never closed with `}}}}`"))?;
        let name = after[..end].trim();
        if name.is_empty() || !name.chars().all(|c| c.is_ascii_lowercase() || c == '_') {
            bail!(
                "line {line}: `{{{{{}}}}}` is not a placeholder name",
                &after[..end]
            );
        }
        let value = values.get(name).with_context(|| {
            let known: Vec<&str> = values.keys().copied().collect();
            format!(
                "line {line}: unknown placeholder {{{{{name}}}}} (known: {})",
                known.join(", ")
            )
        })?;
        out.push_str(value);
        used.insert(name);
        rest = &after[end + 2..];
    }
    out.push_str(rest);
    let unused: Vec<&str> = values
        .keys()
        .copied()
        .filter(|k| !used.contains(k))
        .collect();
    if !unused.is_empty() {
        let names: Vec<String> = unused.iter().map(|n| format!("{{{{{n}}}}}")).collect();
        bail!(
            "the template has no place for {} (its results would be left out)",
            names.join(", ")
        );
    }
    Ok(out)
}

/// The 1-based line number of byte `at` in `text`.
fn line_of(text: &str, at: usize) -> usize {
    text[..at].matches('\n').count() + 1
}

#[cfg(test)]
mod tests {
    use super::*;

    fn values(pairs: &[(&'static str, &str)]) -> BTreeMap<&'static str, String> {
        pairs.iter().map(|(k, v)| (*k, (*v).to_string())).collect()
    }

    #[test]
    fn replaces_each_placeholder_and_keeps_the_rest() {
        let v = values(&[("build", "B"), ("serve", "S {{not scanned}}")]);
        let out = render("# T\n{{build}}\ntext {{ serve }} end\n{{build}}", &v).expect("valid");
        assert_eq!(out, "# T\nB\ntext S {{not scanned}} end\nB");
    }

    #[test]
    fn unknown_placeholder_is_an_error_naming_the_line() {
        let v = values(&[("build", "B")]);
        let e = render("a\n{{build}}\n\n{{buidl}}\n", &v).expect_err("unknown name");
        let msg = format!("{e:#}");
        assert!(msg.contains("line 4"), "{msg}");
        assert!(msg.contains("{{buidl}}"), "{msg}");
    }

    #[test]
    fn a_value_with_no_place_is_an_error() {
        let v = values(&[("build", "B"), ("gpu", "G")]);
        let e = render("{{build}}", &v).expect_err("gpu unused");
        assert!(format!("{e:#}").contains("{{gpu}}"), "{e:#}");
    }

    #[test]
    fn malformed_placeholders_are_errors() {
        let v = values(&[("build", "B")]);
        assert!(render("{{build}}\n{{build", &v).is_err());
        assert!(render("{{build}} {{Build}}", &v).is_err());
        assert!(render("{{build}} {{}}", &v).is_err());
        assert!(render("{{build}} {{a b}}", &v).is_err());
    }
}
