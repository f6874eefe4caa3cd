//! Random access to a DEM's quantized samples, the builder's view of its input.

/// A DEM whose quantized samples can be read by window, from any thread.
pub trait Raster: Sync {
    /// Width in samples.
    fn width(&self) -> u32;
    /// Height in samples.
    fn height(&self) -> u32;
    /// Reads the `w × h` window at `(x0, y0)` (wholly inside the DEM) into `out`,
    /// row-major, as quantized heights.
    fn read_window(&self, x0: u32, y0: u32, w: u32, h: u32, out: &mut [u16]) -> anyhow::Result<()>;
}
