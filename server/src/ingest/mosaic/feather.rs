//! `--feather`: seams between inputs blended by the distance to the higher-priority
//! input's edge (DECISIONS.md "Mixed-grid collections").

use super::Mosaic;
use anyhow::Context;

/// Where an input ends, for `--feather` ([`Piece::edge`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub(super) enum Edge {
    Window([u32; 4]),
    Resampled { metres_per_sample: f64 },
}

impl Edge {
    /// The same edge with its input moved by `(dx, dy)` cells.
    pub(super) fn shifted(self, dx: u32, dy: u32) -> Self {
        match self {
            Self::Window([x0, y0, x1, y1]) => Self::Window([x0 + dx, y0 + dy, x1 + dx, y1 + dy]),
            other @ Self::Resampled { .. } => other,
        }
    }
}

impl Mosaic {
    /// [`Mosaic::read_row`] with `--feather band` (metres; mosaic cells are `cell`
    /// metres): in priority order each piece takes, of the weight its betters left,
    /// the share `min(1, distance to its input's edge / band)`; the row is the
    /// weighted mean. Deep inside an input it is that input alone; at its edge it
    /// fades into what lies below; where nothing lies below it is itself.
    pub(super) fn read_feathered_row(
        &mut self,
        out_row: &mut [f32],
        band: f64,
        cell: [f64; 2],
    ) -> anyhow::Result<()> {
        let r = self.row;
        self.blend.clear();
        self.blend.resize(out_row.len(), (0.0, 1.0));
        for o in &mut self.open {
            let p = &self.pieces[o.index];
            o.reader
                .read_rows(&mut o.row)
                .with_context(|| p.name.clone())?;
            let edge = o.reader.edge_distance();
            for j in 0..p.w as usize {
                let v = o.row[p.src_x as usize + j];
                if v.is_nan() || p.nodata.contains(&v) {
                    continue;
                }
                let col = p.x as usize + j;
                let metres = match p.edge {
                    Edge::Window([x0, y0, x1, y1]) => {
                        let (c, rr) = (col as f64 + 0.5, f64::from(r) + 0.5);
                        ((c - f64::from(x0)) * cell[0])
                            .min((f64::from(x1) - c) * cell[0])
                            .min((rr - f64::from(y0)) * cell[1])
                            .min((f64::from(y1) - rr) * cell[1])
                    }
                    Edge::Resampled { metres_per_sample } => edge
                        .and_then(|e| e.get(p.src_x as usize + j))
                        .map_or(band, |&d| f64::from(d) * metres_per_sample),
                };
                let (sum, left) = &mut self.blend[col];
                let take = *left * (metres / band).clamp(0.0, 1.0);
                *sum += take * f64::from(v);
                *left -= take;
            }
        }
        for (d, &(sum, left)) in out_row.iter_mut().zip(&self.blend) {
            if left < 1.0 {
                *d = (sum / (1.0 - left)) as f32;
            }
        }
        Ok(())
    }
}
