//! Numbers as the plots write them: three significant digits and an SI-style suffix.

/// `v` in at most three significant digits with an SI-style suffix: `0.25`, `12`,
/// `1.23k`, `3.4M`, `5G`, `2T`; `1e-5` and `1.2e15` beyond those; `nan`, `inf`.
pub fn format_compact(v: f64) -> String {
    if v.is_nan() {
        return "nan".into();
    }
    if v.is_infinite() {
        return if v > 0.0 { "inf" } else { "-inf" }.into();
    }
    if v == 0.0 {
        return "0".into();
    }
    let sign = if v < 0.0 { "-" } else { "" };
    let a = v.abs();
    let scientific = || {
        let s = format!("{a:.2e}");
        let (mantissa, exp) = s.split_once('e').unwrap_or((&s, "0"));
        format!("{sign}{}e{exp}", trim_zeros(mantissa))
    };
    let mut e = a.log10().floor() as i32;
    if !(-3..15).contains(&e) {
        return scientific();
    }
    // Three significant digits: a ≈ m·10^(e−2), 100 ≤ m ≤ 999.
    let digits = |e: i32| (a / 10f64.powi(e - 2)).round();
    let mut m = digits(e);
    for _ in 0..2 {
        if m >= 1000.0 {
            e += 1;
        } else if m < 100.0 {
            e -= 1;
        } else {
            break;
        }
        m = digits(e);
    }
    if !(-3..15).contains(&e) {
        return scientific();
    }
    let (div, suffix) = match e {
        12.. => (12, "T"),
        9.. => (9, "G"),
        6.. => (6, "M"),
        3.. => (3, "k"),
        _ => (0, ""),
    };
    let decimals = (div + 2 - e).max(0) as usize;
    let x = m * 10f64.powi(e - 2 - div);
    format!("{sign}{}{suffix}", trim_zeros(&format!("{x:.decimals$}")))
}

/// "1.50" → "1.5", "2.00" → "2", "120" → "120".
fn trim_zeros(s: &str) -> &str {
    if s.contains('.') {
        s.trim_end_matches('0').trim_end_matches('.')
    } else {
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn numbers_format_compactly() {
        let cases = [
            (0.0, "0"),
            (-0.0, "0"),
            (0.25, "0.25"),
            (0.125, "0.125"),
            (0.001, "0.001"),
            (1.0, "1"),
            (12.0, "12"),
            (12.34, "12.3"),
            (999.0, "999"),
            (999.6, "1k"),
            (1200.0, "1.2k"),
            (1234.0, "1.23k"),
            (12_345.0, "12.3k"),
            (123_456.0, "123k"),
            (999_999.0, "1M"),
            (3.4e6, "3.4M"),
            (-1500.0, "-1.5k"),
            (5e9, "5G"),
            (2.5e13, "25T"),
            (1e-5, "1e-5"),
            (1.234e-7, "1.23e-7"),
            (1.2e15, "1.2e15"),
            (f64::NAN, "nan"),
            (f64::INFINITY, "inf"),
            (f64::NEG_INFINITY, "-inf"),
        ];
        for (v, want) in cases {
            assert_eq!(format_compact(v), want, "{v}");
        }
        for k in -300..300 {
            let v = 10f64.powi(k);
            assert!(!format_compact(v).is_empty());
            assert!(!format_compact(v * 0.9999).is_empty());
        }
    }
}
