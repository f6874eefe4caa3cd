//! Colour ramps in `gdaldem color-relief`'s text format, and the built-in ones.
//!
//! A ramp file has one entry per line: a value, then `R G B [A]` (0–255) or a colour
//! name (`white`, `black`, `red`, `green`, `blue`, `yellow`, `magenta`, `cyan`,
//! `aqua`, `grey`/`gray`, `orange`, `brown`, `purple`/`violet`, `indigo`, with
//! `gdaldem`'s values) and an optional alpha. Fields are separated by spaces, tabs,
//! commas or colons; lines starting with `#` or `/` are comments. The value is a
//! number, a percentage `P%` of the layer's range (for heights, the dataset's lowest
//! to highest height: the same for every tile, so tiles join), or `nv`, the colour of
//! pixels without data (transparent when the ramp has none). A GMT `.cpt` file
//! (`# COLOR_MODEL = RGB`, lines of `z0 R G B z1 R G B`, and `N R G B`) is read too.
//!
//! A value between two entries is coloured between theirs as `gdaldem` does:
//! `⌊0.45 + c₀ + t·(c₁ − c₀)⌋` per channel for `t` the value's fraction of the way;
//! below the first entry or above the last, the end's colour. Two entries with one
//! value make a step.
//!
//! Bad files are refused with the line and the reason ([`RampError`]), never
//! guessed at.

use std::fmt;

/// At most this many entries in one ramp (gdaldem has no limit; a ramp this long is
/// no longer a ramp, and the bound keeps lookups cheap).
pub const MAX_ENTRIES: usize = 4096;

/// Why a ramp file is refused.
#[derive(Clone, Debug, PartialEq, Eq, thiserror::Error)]
#[error("line {line}: {reason}")]
pub struct RampError {
    /// 1-based; 0 for the file as a whole.
    pub line: usize,
    pub reason: String,
}

/// An entry's value before the layer's range is known.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Value {
    At(f64),
    /// A fraction (0–1) of the layer's range.
    Fraction(f64),
}

/// A parsed ramp, its percentages not yet resolved.
#[derive(Clone, Debug, PartialEq)]
pub struct RampSpec {
    entries: Vec<(Value, [u8; 4])>,
    nodata: Option<[u8; 4]>,
}

/// A ramp ready to colour values: entries sorted by value (stable, so equal values
/// keep the file's order and make a step).
#[derive(Clone, Debug, PartialEq)]
pub struct Ramp {
    values: Vec<f64>,
    colours: Vec<[u8; 4]>,
    /// The colour of pixels without data (`nv`); transparent when `None`.
    pub nodata: Option<[u8; 4]>,
}

const NAMED: [(&str, [f64; 3]); 16] = [
    ("white", [1.0, 1.0, 1.0]),
    ("black", [0.0, 0.0, 0.0]),
    ("red", [1.0, 0.0, 0.0]),
    ("green", [0.0, 1.0, 0.0]),
    ("blue", [0.0, 0.0, 1.0]),
    ("yellow", [1.0, 1.0, 0.0]),
    ("magenta", [1.0, 0.0, 1.0]),
    ("cyan", [0.0, 1.0, 1.0]),
    ("aqua", [0.0, 0.75, 0.75]),
    ("grey", [0.75, 0.75, 0.75]),
    ("gray", [0.75, 0.75, 0.75]),
    ("orange", [1.0, 0.5, 0.0]),
    ("brown", [0.75, 0.5, 0.25]),
    ("purple", [0.5, 0.0, 1.0]),
    ("violet", [0.5, 0.0, 1.0]),
    ("indigo", [0.0, 0.5, 1.0]),
];

fn named(name: &str) -> Option<[u8; 3]> {
    NAMED
        .iter()
        .find(|(n, _)| n.eq_ignore_ascii_case(name))
        // gdaldem truncates 255 × the fraction (0.75 → 191).
        .map(|(_, c)| c.map(|v| (255.0 * v) as u8))
}

fn channel(s: &str, what: &str) -> Result<u8, String> {
    s.parse::<u8>()
        .map_err(|_| format!("{what} {s:?} is not a whole number from 0 to 255"))
}

fn value(s: &str) -> Result<Value, String> {
    if let Some(p) = s.strip_suffix('%') {
        let pct: f64 = p
            .parse()
            .map_err(|_| format!("{s:?} is not a percentage"))?;
        if !(0.0..=100.0).contains(&pct) {
            return Err(format!("{s:?} is not a percentage from 0 to 100"));
        }
        return Ok(Value::Fraction(pct / 100.0));
    }
    match s.parse::<f64>() {
        Ok(v) if v.is_finite() => Ok(Value::At(v)),
        _ => Err(format!("{s:?} is not a value (a number, P%, or nv)")),
    }
}

impl RampSpec {
    /// Reads a ramp file's text.
    pub fn parse(text: &str) -> Result<Self, RampError> {
        let mut entries = Vec::new();
        let mut nodata = None;
        let mut cpt = false;
        for (k, raw) in text.lines().enumerate() {
            let line = k + 1;
            let err = |reason: String| RampError { line, reason };
            let t = raw.trim();
            if t.starts_with('#') && t.contains("COLOR_MODEL") {
                let model = t.split_once('=').map(|(_, m)| m.trim());
                if model != Some("RGB") {
                    return Err(err("only GMT's COLOR_MODEL = RGB is read".into()));
                }
                cpt = true;
                continue;
            }
            let f: Vec<&str> = t
                .split([' ', '\t', ',', ':'])
                .filter(|s| !s.is_empty())
                .collect();
            if f.is_empty() || f[0].starts_with('#') || f[0].starts_with('/') {
                continue;
            }
            if cpt {
                match (f.len(), f[0]) {
                    (4, "N") => {
                        let [r, g, b] = rgb(&f[1..4]).map_err(err)?;
                        nodata = Some([r, g, b, 255]);
                    }
                    (4, "B" | "F") => {}
                    (8, _) => {
                        for part in [&f[0..4], &f[4..8]] {
                            let v = value(part[0]).map_err(err)?;
                            let [r, g, b] = rgb(&part[1..4]).map_err(err)?;
                            entries.push((v, [r, g, b, 255]));
                        }
                    }
                    (n, _) => {
                        return Err(err(format!(
                            "a GMT colour table line has 8 fields (z0 R G B z1 R G B) or is N/B/F R G B, not {n} fields"
                        )));
                    }
                }
            } else {
                let colour = match f.len() {
                    2 | 3 if f[1].parse::<f64>().is_ok() => {
                        return Err(err(format!(
                            "a colour is R G B [A] (three or four numbers) or a name; this line has {} number(s) after the value",
                            f.len() - 1
                        )));
                    }
                    2 | 3 => {
                        let [r, g, b] = named(f[1]).ok_or_else(|| {
                            err(format!(
                                "unknown colour name {:?} (give R G B, or one of gdaldem's names: {})",
                                f[1],
                                NAMED.map(|(n, _)| n).join(", ")
                            ))
                        })?;
                        let a = f
                            .get(2)
                            .map_or(Ok(255), |a| channel(a, "alpha"))
                            .map_err(err)?;
                        [r, g, b, a]
                    }
                    4 | 5 => {
                        let [r, g, b] = rgb(&f[1..4]).map_err(err)?;
                        let a = f
                            .get(4)
                            .map_or(Ok(255), |a| channel(a, "alpha"))
                            .map_err(err)?;
                        [r, g, b, a]
                    }
                    n => {
                        return Err(err(format!(
                            "an entry is a value and a colour (R G B [A], or a name [A]); this line has {n} fields"
                        )));
                    }
                };
                if f[0].eq_ignore_ascii_case("nv") {
                    nodata = Some(colour);
                } else {
                    entries.push((value(f[0]).map_err(err)?, colour));
                }
            }
            if entries.len() > MAX_ENTRIES {
                return Err(err(format!("more than {MAX_ENTRIES} entries")));
            }
        }
        if entries.is_empty() {
            return Err(RampError {
                line: 0,
                reason: "no entries (each line is a value and a colour, e.g. \"1000 120 90 40\")"
                    .into(),
            });
        }
        Ok(Self { entries, nodata })
    }

    /// The ramp with percentages taken of `range` (lowest, highest); `None` when it
    /// has percentages and no range is given.
    pub fn resolve(&self, range: Option<(f64, f64)>) -> Option<Ramp> {
        let mut pairs: Vec<(f64, [u8; 4])> = self
            .entries
            .iter()
            .map(|&(v, c)| match v {
                Value::At(x) => Some((x, c)),
                Value::Fraction(f) => range.map(|(lo, hi)| (lo + f * (hi - lo), c)),
            })
            .collect::<Option<_>>()?;
        pairs.sort_by(|a, b| a.0.total_cmp(&b.0));
        let (values, colours) = pairs.into_iter().unzip();
        Some(Ramp {
            values,
            colours,
            nodata: self.nodata,
        })
    }
}

fn rgb(f: &[&str]) -> Result<[u8; 3], String> {
    Ok([
        channel(f[0], "red")?,
        channel(f[1], "green")?,
        channel(f[2], "blue")?,
    ])
}

impl Ramp {
    /// The colour of value `v` (finite).
    pub fn colour(&self, v: f64) -> [u8; 4] {
        let n = self.values.len();
        let i = self.values.partition_point(|&e| e < v);
        if i == 0 {
            return self.colours[0];
        }
        if i == n {
            return self.colours[n - 1];
        }
        let (v0, v1) = (self.values[i - 1], self.values[i]);
        let (c0, c1) = (self.colours[i - 1], self.colours[i]);
        let t = (v - v0) / (v1 - v0);
        std::array::from_fn(|k| {
            let (a, b) = (f64::from(c0[k]), f64::from(c1[k]));
            // Truncation, as gdaldem's int cast (the value is ≥ 0.45 > 0).
            (0.45 + a + t * (b - a)).clamp(0.0, 255.0) as u8
        })
    }
}

/// The built-in ramps: name, what it is for, and its text in the file format.
pub const BUILT_IN: [(&str, &str, &str); 5] = [
    (
        "hypsometric",
        "heights in metres: blue seas, green lowlands through browns to white summits above 4 500 m",
        "# Sea\n-11000 8 29 88\n-5000 25 75 145\n-200 80 145 205\n0 165 210 235\n\
         # Land (a step at 0 m)\n0 52 120 70\n200 95 155 80\n500 170 190 110\n1000 215 195 125\n\
         1500 190 140 85\n2000 160 100 70\n3000 140 120 110\n4000 215 215 215\n4500 255 255 255\n",
    ),
    (
        "relative",
        "the dataset's own range: green at its lowest through tan and brown to white at its highest",
        "0% 40 110 60\n25% 150 185 95\n50% 225 205 130\n75% 165 115 75\n100% 255 255 255\n",
    ),
    (
        "grey",
        "the dataset's own range from black to white",
        "0% 0 0 0\n100% 255 255 255\n",
    ),
    (
        "slope",
        "slopes in degrees: white when flat, yellow from 25°, orange at 30°, red at 35°, purple at 45°, black at 90°",
        "0 255 255 255\n10 255 255 190\n25 255 235 80\n30 255 165 0\n35 230 60 30\n40 180 0 60\n\
         45 120 0 120\n90 0 0 0\n",
    ),
    (
        "slope-percent",
        "the slope ramp for slopes in percent (the same colours at 100·tan of its angles)",
        "0 255 255 255\n17.633 255 255 190\n46.631 255 235 80\n57.735 255 165 0\n70.021 230 60 30\n\
         83.910 180 0 60\n100 120 0 120\n10000 0 0 0\n",
    ),
];

/// A built-in ramp by name.
pub fn built_in(name: &str) -> Option<RampSpec> {
    BUILT_IN
        .iter()
        .find(|(n, _, _)| *n == name)
        .map(|(_, _, text)| RampSpec::parse(text).expect("built-in ramps parse"))
}

impl fmt::Display for Ramp {
    /// The ramp in the file format (what TileJSON and WMTS abstracts describe).
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (v, [r, g, b, a]) in self.values.iter().zip(&self.colours) {
            writeln!(f, "{v} {r} {g} {b} {a}")?;
        }
        if let Some([r, g, b, a]) = self.nodata {
            writeln!(f, "nv {r} {g} {b} {a}")?;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ramp(text: &str) -> Ramp {
        RampSpec::parse(text)
            .unwrap()
            .resolve(Some((100.0, 300.0)))
            .unwrap()
    }

    #[test]
    fn values_between_entries_are_interpolated_as_gdaldem_does() {
        let r = ramp("0 0 0 0\n100 255 100 10 128\n");
        // 0.45 + 0 + 0.5·255 = 127.95 → 127; 0.45 + 50 → 50; 0.45 + 5 → 5.
        assert_eq!(r.colour(50.0), [127, 50, 5, 191]);
        assert_eq!(r.colour(-5.0), [0, 0, 0, 255]);
        assert_eq!(r.colour(100.0), [255, 100, 10, 128]);
        assert_eq!(r.colour(1e9), [255, 100, 10, 128]);
        // 0.45 + 0.999·255 = 255.2 → 255; and just below a half: 0.45 + 0.2·255 = 51.45.
        assert_eq!(r.colour(99.9)[0], 255);
        assert_eq!(r.colour(20.0)[0], 51);
    }

    #[test]
    fn the_forms_gdaldem_reads() {
        let r =
            ramp("# a comment\n/ another\n\n10%,white\n  50%\tred:200\n100% 0 0 255\nnv 1 2 3 4\n");
        assert_eq!(r.values, vec![120.0, 200.0, 300.0]);
        assert_eq!(
            r.colours,
            vec![[255, 255, 255, 255], [255, 0, 0, 200], [0, 0, 255, 255]]
        );
        assert_eq!(r.nodata, Some([1, 2, 3, 4]));
        // gdaldem's grey is 0.75 × 255 truncated.
        assert_eq!(ramp("0 grey").colour(0.0), [191, 191, 191, 255]);
    }

    #[test]
    fn equal_values_make_a_step_in_file_order() {
        let r = ramp("0 0 0 0\n10 255 0 0\n10 0 0 255\n20 0 0 255\n");
        // 0.45 + 0.99·255 = 252.9.
        assert_eq!(r.colour(9.9), [252, 0, 0, 255]);
        assert_eq!(r.colour(10.0), [255, 0, 0, 255]);
        assert_eq!(r.colour(10.001), [0, 0, 255, 255]);
    }

    #[test]
    fn gmt_colour_tables() {
        let r = ramp(
            "# COLOR_MODEL = RGB\n0 0 0 0 10 10 10 10\n10 10 10 10 20 200 200 200\nB 0 0 0\nN 9 9 9\n",
        );
        assert_eq!(r.colour(15.0), [105, 105, 105, 255]);
        assert_eq!(r.nodata, Some([9, 9, 9, 255]));
        let e = RampSpec::parse("# COLOR_MODEL = HSV\n0 0 0 0 1 1 1 1\n").unwrap_err();
        assert_eq!(e.line, 1);
    }

    #[test]
    fn malformed_files_are_refused_with_the_line() {
        for (text, line, says) in [
            ("0 0 0 0\n100 300 0 0\n", 2, "red \"300\""),
            ("0 0 0\n", 1, "2 number(s) after the value"),
            ("abc 1 2 3\n", 1, "\"abc\" is not a value"),
            ("150% 1 2 3\n", 1, "from 0 to 100"),
            ("0 chartreuse\n", 1, "unknown colour name \"chartreuse\""),
            ("0 1 2 3 4 5 6\n", 1, "7 fields"),
            ("inf 1 2 3\n", 1, "is not a value"),
            ("# only comments\n", 0, "no entries"),
            ("nv 0 0 0 0\n", 0, "no entries"),
        ] {
            let e = RampSpec::parse(text).unwrap_err();
            assert_eq!(e.line, line, "{text:?}: {e}");
            assert!(e.reason.contains(says), "{text:?}: {e}");
        }
        let long = (0..=MAX_ENTRIES).fold(String::new(), |s, k| s + &k.to_string() + " 1 2 3\n");
        assert!(
            RampSpec::parse(&long)
                .unwrap_err()
                .reason
                .contains("more than")
        );
    }

    #[test]
    fn percentages_need_a_range() {
        let spec = RampSpec::parse("0% black\n100% white\n").unwrap();
        assert!(spec.resolve(None).is_none());
        assert_eq!(
            spec.resolve(Some((-10.0, 10.0))).unwrap().values,
            vec![-10.0, 10.0]
        );
    }

    #[test]
    fn built_in_ramps_parse_and_the_slope_ramps_agree() {
        for (name, _, _) in BUILT_IN {
            assert!(built_in(name).is_some(), "{name}");
        }
        let deg = built_in("slope").unwrap().resolve(None).unwrap();
        let pct = built_in("slope-percent").unwrap().resolve(None).unwrap();
        // The same colours at the same slopes, at every entry of the degree ramp.
        for d in [0.0f64, 10.0, 25.0, 30.0, 35.0, 40.0, 45.0] {
            let p = 100.0 * d.to_radians().tan();
            assert_eq!(deg.colour(d), pct.colour(p), "{d}°");
        }
        assert!(built_in("nope").is_none());
    }
}
