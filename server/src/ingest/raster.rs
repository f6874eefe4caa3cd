//! Random access to a DEM's quantized samples: the builder's view of its input
//! (a synthetic DEM, or the builder's spooled copy of a streamed one).

/// A DEM whose quantized samples can be read by window, from any thread.
pub trait Raster: Sync {
    /// Width in samples.
    fn width(&self) -> u32;
    /// Height in samples.
    fn height(&self) -> u32;
    /// Reads the `w × h` window at `(x0, y0)` (wholly inside the DEM) into `out`,
    /// row-major, as quantized heights.
    fn read_window(&self, x0: u32, y0: u32, w: u32, h: u32, out: &mut [u16]) -> anyhow::Result<()>;

    /// Whether each sample of the window held input data (`false`: it was no-data
    /// and [`Raster::read_window`] returns a filled value). Rasters without no-data
    /// keep the default.
    fn read_validity(
        &self,
        _x0: u32,
        _y0: u32,
        _w: u32,
        _h: u32,
        out: &mut [bool],
    ) -> anyhow::Result<()> {
        out.fill(true);
        Ok(())
    }

    /// Whether any sample is no-data (when not, validity need not be read).
    fn has_nodata(&self) -> bool {
        false
    }

    /// Valid and no-data sample counts by "depth": index `d` counts samples whose
    /// column and row are both multiples of `2^d` but not both of `2^(d+1)`
    /// (`d` capped at 32), so level `L` of `L_max` holds the sum over
    /// `d ≥ L_max − L` (see [`crate::builder::level_counts`]).
    fn depth_counts(&self) -> DepthCounts;
}

/// Per depth `d` (see [`Raster::depth_counts`]): `[valid, filled]` sample counts.
pub type DepthCounts = [[u64; 2]; 33];

/// The depth of sample `(x, y)`: the largest `d ≤ 32` with `2^d` dividing both.
pub fn depth(x: u32, y: u32) -> usize {
    (x | y).trailing_zeros().min(32) as usize
}

/// Depth counts of a `width × height` raster whose samples are all valid.
pub fn all_valid_depth_counts(width: u32, height: u32) -> DepthCounts {
    let mut c = [[0u64; 2]; 33];
    // Samples on the 2^d lattice: ceil(W / 2^d) · ceil(H / 2^d); depth d holds those
    // on the 2^d lattice minus those on the 2^(d+1) one.
    let on = |d: u32| -> u64 {
        if d >= 32 {
            1
        } else {
            u64::from(width.div_ceil(1 << d)) * u64::from(height.div_ceil(1 << d))
        }
    };
    for d in 0..33u32 {
        let next = if d == 32 { 0 } else { on(d + 1) };
        c[d as usize][0] = on(d) - next;
    }
    c
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn depth_counts_of_a_full_raster_add_up_per_lattice() {
        let (w, h) = (13u32, 6u32);
        let mut brute = [[0u64; 2]; 33];
        for y in 0..h {
            for x in 0..w {
                brute[depth(x, y)][0] += 1;
            }
        }
        assert_eq!(all_valid_depth_counts(w, h), brute);
        assert_eq!(brute.iter().map(|c| c[0]).sum::<u64>(), 78);
        assert_eq!(brute[32][0], 1, "only (0, 0) lies on every lattice");
    }
}
