//! The Prometheus text exposition format, as `/metrics` serves it.

use std::collections::BTreeMap;

/// One sample line: name, labels, value.
#[derive(Debug, Clone)]
pub struct Sample {
    pub name: String,
    pub labels: BTreeMap<String, String>,
    pub value: f64,
}

/// Parses the sample lines of the text exposition format (label values without
/// escaped quotes, which is all ours need).
pub fn parse_metrics(text: &str) -> Vec<Sample> {
    let mut out = Vec::new();
    for line in text.lines() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        let (series, value) = line.rsplit_once(' ').unwrap();
        let value: f64 = value.parse().unwrap();
        let (name, labels) = match series.split_once('{') {
            Some((n, rest)) => {
                let rest = rest.strip_suffix('}').unwrap();
                let labels = rest
                    .split("\",")
                    .filter(|kv| !kv.is_empty())
                    .map(|kv| {
                        let (k, v) = kv.split_once('=').unwrap();
                        (k.trim().to_string(), v.trim().trim_matches('"').to_string())
                    })
                    .collect();
                (n.to_string(), labels)
            }
            None => (series.to_string(), BTreeMap::new()),
        };
        out.push(Sample {
            name,
            labels,
            value,
        });
    }
    out
}

/// `tessera_compute_total{kind, outcome}`, or a labelled gauge with `kind` alone.
pub fn compute(samples: &[Sample], name: &str, kind: &str, outcome: Option<&str>) -> f64 {
    samples
        .iter()
        .filter(|s| {
            s.name == name
                && s.labels.get("kind").is_some_and(|k| k == kind)
                && outcome.is_none_or(|o| s.labels.get("outcome").is_some_and(|v| v == o))
        })
        .map(|s| s.value)
        .sum()
}

/// The value of an unlabelled metric (0 when absent).
pub fn metric(samples: &[Sample], name: &str) -> f64 {
    samples
        .iter()
        .filter(|s| s.name == name && s.labels.is_empty())
        .map(|s| s.value)
        .sum()
}
