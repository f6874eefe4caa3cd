//! The few statistics the reports print and the charts' axes use.

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
