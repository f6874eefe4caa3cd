//! The few statistics the reports print and the charts' axes use: the median, the
//! finite range of a series, a constant's range widened, and "nice" tick steps.

/// The median of `values` (the mean of the two middle ones for an even count), or
/// `None` for none. NaNs sort last; callers filter them when they can occur.
///
/// ```
/// use tessera_charts::stats::median;
/// assert_eq!(median(&[3.0, 1.0, 2.0]), Some(2.0));
/// assert_eq!(median(&[4.0, 1.0, 2.0, 3.0]), Some(2.5));
/// assert_eq!(median(&[]), None);
/// ```
pub fn median(values: &[f64]) -> Option<f64> {
    let mut v = values.to_vec();
    v.sort_by(f64::total_cmp);
    let n = v.len();
    match n {
        0 => None,
        _ if n % 2 == 1 => Some(v[n / 2]),
        _ => Some(f64::midpoint(v[n / 2 - 1], v[n / 2])),
    }
}

/// The smallest 1, 2 or 5 × 10^k at least `raw` (1 for anything not positive and
/// finite): tick and label steps that read well.
///
/// ```
/// use tessera_charts::stats::nice_step;
/// assert_eq!(nice_step(0.3), 0.5);
/// assert_eq!(nice_step(7.0), 10.0);
/// assert_eq!(nice_step(120.0), 200.0);
/// ```
pub fn nice_step(raw: f64) -> f64 {
    if !(raw.is_finite() && raw > 0.0) {
        return 1.0;
    }
    let base = 10f64.powf(raw.log10().floor());
    // The tolerance keeps exact powers (e.g. 0.1 computed as 0.1000…01) on themselves.
    [1.0, 2.0, 5.0, 10.0]
        .into_iter()
        .map(|m| m * base)
        .find(|&s| s >= raw * (1.0 - 1e-9))
        .unwrap_or(10.0 * base)
}

/// The smallest and largest of the finite `values` (NaN and ±∞ left out), or
/// `None` without any.
///
/// ```
/// use tessera_charts::stats::min_max;
/// assert_eq!(min_max([3.0, f64::NAN, -1.0, f64::INFINITY]), Some((-1.0, 3.0)));
/// assert_eq!(min_max([f64::NAN]), None);
/// ```
pub fn min_max(values: impl IntoIterator<Item = f64>) -> Option<(f64, f64)> {
    values
        .into_iter()
        .filter(|v| v.is_finite())
        .fold(None, |acc, v| {
            Some(acc.map_or((v, v), |(lo, hi): (f64, f64)| (lo.min(v), hi.max(v))))
        })
}

/// The axis range for values from `lo` to `hi`: as it is when `lo < hi`; around a
/// constant, widened to ±10 % of it (±1 around 0), so that it has a height.
///
/// ```
/// use tessera_charts::stats::widen_flat;
/// assert_eq!(widen_flat(1.0, 3.0), (1.0, 3.0));
/// assert_eq!(widen_flat(0.0, 0.0), (-1.0, 1.0));
/// assert_eq!(widen_flat(-50.0, -50.0), (-55.0, -45.0));
/// ```
pub fn widen_flat(lo: f64, hi: f64) -> (f64, f64) {
    if lo < hi {
        (lo, hi)
    } else {
        let d = if lo == 0.0 { 1.0 } else { lo.abs() * 0.1 };
        (lo - d, hi + d)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nice_steps_cover_their_input() {
        for raw in [1e-3, 0.3, 1.0, 1.5, 3.0, 9.9, 10.0, 11.0, 4321.0] {
            let s = nice_step(raw);
            assert!(s >= raw * (1.0 - 1e-9) && s < raw * 10.0, "{raw} → {s}");
        }
        assert_eq!(nice_step(f64::NAN), 1.0);
        assert_eq!(nice_step(-2.0), 1.0);
    }
}
