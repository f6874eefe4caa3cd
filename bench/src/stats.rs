//! Medians with their spread, and how numbers are written in the report.
//!
//! Every row of BENCHMARKS.md is a median of repeated runs with the smallest and
//! largest run beside it, "2.16 (2.14–2.18)", so a reader sees at once how much
//! the machine wobbled. Numbers keep three significant digits but never lose
//! integer digits (28318 stays 28318, 0.89 becomes 0.890), and the median and its
//! range share one number of decimals so they line up.

use std::collections::BTreeMap;

/// The one median of the project (mean of the two middle values for an even count).
pub use tessera_charts::stats::median;

/// A median with the smallest and largest value it was taken over.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Spread {
    pub median: f64,
    pub min: f64,
    pub max: f64,
    /// How many values.
    pub n: usize,
}

impl Spread {
    /// `None` when `values` is empty.
    pub fn of(values: impl IntoIterator<Item = f64>) -> Option<Self> {
        let v: Vec<f64> = values.into_iter().collect();
        let median = median(&v)?;
        Some(Self {
            median,
            min: v.iter().copied().fold(f64::INFINITY, f64::min),
            max: v.iter().copied().fold(f64::NEG_INFINITY, f64::max),
            n: v.len(),
        })
    }

    /// "median (min–max)"; a lone value is written alone.
    pub fn fmt(&self) -> String {
        self.fmt_unit("")
    }

    /// [`Self::fmt`] with `unit` after each number ("96.2% (95.0–97.1%)" for "%").
    pub fn fmt_unit(&self, unit: &str) -> String {
        let d = decimals(if self.median == 0.0 {
            self.min.abs().max(self.max.abs())
        } else {
            self.median
        });
        // No more decimals than the values have: counts stay "21 (21–21)".
        let d = [self.median, self.min, self.max]
            .into_iter()
            .map(|v| exact_decimals(v, d))
            .max()
            .unwrap_or(d);
        let f = |v: f64| format!("{}{unit}", fixed(v, d));
        if self.n <= 1 {
            f(self.median)
        } else {
            format!(
                "{} ({}–{})",
                f(self.median),
                fixed(self.min, d),
                f(self.max)
            )
        }
    }

    /// The same spread with every value multiplied by `k` (fractions to percent).
    pub fn scaled(&self, k: f64) -> Self {
        Self {
            median: self.median * k,
            min: self.min * k,
            max: self.max * k,
            n: self.n,
        }
    }
}

/// Decimals that give `v` three significant digits without dropping integer
/// digits (at most 6).
fn decimals(v: f64) -> usize {
    if v == 0.0 || !v.is_finite() {
        return 0;
    }
    (2 - v.abs().log10().floor() as i64).clamp(0, 6) as usize
}

/// The fewest decimals, at most `d`, that write `v` as exactly as `d` would.
fn exact_decimals(v: f64, d: usize) -> usize {
    (0..d)
        .find(|&k| {
            let scale = 10f64.powi(k as i32);
            ((v * scale).round() / scale - v).abs() <= 1e-9 * v.abs().max(1.0)
        })
        .unwrap_or(d)
}

/// `v` with `d` decimals; "—" for a non-finite value, and no "-0".
fn fixed(v: f64, d: usize) -> String {
    if !v.is_finite() {
        return "—".into();
    }
    let s = format!("{v:.d$}");
    if s.starts_with('-') && s[1..].chars().all(|c| c == '0' || c == '.') {
        s[1..].to_string()
    } else {
        s
    }
}

/// `v` with three significant digits, keeping every integer digit, without
/// trailing zeros after the point ("6", "0.89", "44.5").
pub fn num(v: f64) -> String {
    let d = decimals(v);
    fixed(v, exact_decimals(v, d))
}

/// A ratio: "0.60×", "6.1×", "45×".
pub fn ratio(r: f64) -> String {
    let d = if !r.is_finite() {
        0
    } else if r.abs() < 10.0 {
        2
    } else {
        usize::from(r.abs() < 100.0)
    };
    format!("{}×", fixed(r, d))
}

/// A fraction as a percentage with one decimal: 0.962 → "96.2%".
pub fn pct(fraction: f64) -> String {
    format!("{}%", fixed(fraction * 100.0, 1))
}

/// A fraction's spread as percentages with one decimal: "96.2% (95.0–97.1%)".
pub fn pct_spread(s: &Spread) -> String {
    let p = s.scaled(100.0);
    if p.n <= 1 {
        format!("{}%", fixed(p.median, 1))
    } else {
        format!(
            "{}% ({}–{}%)",
            fixed(p.median, 1),
            fixed(p.min, 1),
            fixed(p.max, 1)
        )
    }
}

/// Run-paired ratios `a / b`: the ratio of the medians, and the spread of the
/// per-run ratios (run k of `a` against run k of `b`, for runs both have).
/// `None` when either side is empty or `b`'s median is not positive.
pub fn paired_ratio(a: &[(u32, f64)], b: &[(u32, f64)]) -> Option<(f64, Option<Spread>)> {
    let ma = median(&a.iter().map(|x| x.1).collect::<Vec<_>>())?;
    let mb = median(&b.iter().map(|x| x.1).collect::<Vec<_>>())?;
    if mb <= 0.0 {
        return None;
    }
    let by_run: BTreeMap<u32, f64> = b.iter().copied().collect();
    let per_run = a
        .iter()
        .filter_map(|(run, va)| by_run.get(run).filter(|vb| **vb > 0.0).map(|vb| va / vb));
    Some((ma / mb, Spread::of(per_run)))
}

/// A paired ratio as "0.82× (0.79–0.85×)", the range from the per-run ratios.
pub fn fmt_paired(r: f64, per_run: Option<&Spread>) -> String {
    match per_run {
        Some(s) if s.n > 1 => {
            let strip = |v: f64| ratio(v).trim_end_matches('×').to_string();
            format!("{} ({}–{}×)", ratio(r), strip(s.min), strip(s.max))
        }
        _ => ratio(r),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn median_of_odd_even_and_empty() {
        assert_eq!(median(&[3.0, 1.0, 2.0]), Some(2.0));
        assert_eq!(median(&[4.0, 1.0, 3.0, 2.0]), Some(2.5));
        assert_eq!(median(&[7.0]), Some(7.0));
        assert_eq!(median(&[]), None);
    }

    #[test]
    fn spread_has_min_max_and_count() {
        let s = Spread::of([2.18, 2.14, 2.16]).expect("three values");
        assert_eq!((s.median, s.min, s.max, s.n), (2.16, 2.14, 2.18, 3));
        assert!(Spread::of([]).is_none());
    }

    #[test]
    fn spreads_keep_three_significant_digits_and_shared_decimals() {
        let f = |v: &[f64]| Spread::of(v.iter().copied()).expect("values").fmt();
        assert_eq!(f(&[2.16, 2.14, 2.18]), "2.16 (2.14–2.18)");
        assert_eq!(f(&[28318.0, 28011.4, 29000.2]), "28318 (28011–29000)");
        assert_eq!(f(&[0.89, 0.891, 0.889]), "0.890 (0.889–0.891)");
        assert_eq!(f(&[11.3, 9.8, 12.0]), "11.3 (9.8–12.0)");
        assert_eq!(f(&[0.0, 0.0, 0.0]), "0 (0–0)");
        assert_eq!(f(&[0.0, 0.0, 0.25]), "0.00 (0.00–0.25)");
        assert_eq!(f(&[95.1]), "95.1");
        // Counts and halves of counts keep no needless zeros.
        assert_eq!(f(&[21.0, 21.0]), "21 (21–21)");
        assert_eq!(f(&[7.0, 8.0]), "7.5 (7.0–8.0)");
        assert_eq!(f(&[77.0, 77.0, 77.0]), "77 (77–77)");
        let s = Spread::of([0.962, 0.95, 0.971]).expect("values");
        assert_eq!(pct_spread(&s), "96.2% (95.0–97.1%)");
        assert_eq!(s.scaled(100.0).fmt_unit("%"), "96.2% (95.0–97.1%)");
    }

    #[test]
    fn single_numbers_ratios_and_percentages() {
        assert_eq!(num(303_242.0), "303242");
        assert_eq!(num(44.45), "44.5");
        assert_eq!(num(0.00123), "0.00123");
        assert_eq!(num(-0.0001), "-0.0001");
        assert_eq!(num(6.0), "6");
        assert_eq!(num(0.89), "0.89");
        assert_eq!(num(2.0 / 3.0), "0.667");
        assert_eq!(num(f64::NAN), "—");
        assert_eq!(ratio(0.6), "0.60×");
        assert_eq!(ratio(6.1), "6.10×");
        assert_eq!(ratio(45.26), "45.3×");
        assert_eq!(ratio(512.0), "512×");
        assert_eq!(pct(0.9925), "99.2%");
        assert_eq!(pct(1.0), "100.0%");
    }

    #[test]
    fn paired_ratios_pair_runs_by_number() {
        let a = [(1, 10.0), (2, 12.0), (3, 30.0)];
        let b = [(1, 5.0), (2, 3.0), (3, 10.0)];
        let (r, per_run) = paired_ratio(&a, &b).expect("both sides");
        // Medians 12 / 5; per run 2, 4, 3.
        assert_eq!(r, 12.0 / 5.0);
        let s = per_run.expect("runs in common");
        assert_eq!((s.median, s.min, s.max), (3.0, 2.0, 4.0));
        assert_eq!(fmt_paired(r, Some(&s)), "2.40× (2.00–4.00×)");
        // Runs without a partner are left out of the per-run ratios.
        let (_, per_run) = paired_ratio(&[(1, 1.0), (4, 9.0)], &[(1, 2.0)]).expect("sides");
        assert_eq!(per_run.map(|s| s.n), Some(1));
        assert!(paired_ratio(&a, &[]).is_none());
        assert!(paired_ratio(&a, &[(1, 0.0)]).is_none());
    }
}
