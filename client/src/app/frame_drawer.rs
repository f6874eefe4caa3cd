//! Drawing inside a flight: what the flight loop ([`super::fly::fly`]) asks of a
//! renderer at each step ([`FrameDrawer`]; headless rendering implements it under
//! the `render` feature), and the rendering figures a flight records per frame
//! ([`RenderRecord`], in `stats.jsonl`) and in its summary ([`RenderSummary`]).
//! A flight without a drawer selects and streams only, and needs no GPU.

use crate::camera::Camera;
use crate::select::{FrameStats, Selection, Selector, Wanted};
use crate::stream::Streamer;
use crate::stream::pool::TilePool;

/// A renderer as a flight drives it. The flight calls it in this order: once
/// [`upload_preloaded`](Self::upload_preloaded) before its clock starts; then each
/// frame [`settles`](Self::settles), [`select`](Self::select) (and, while a settled
/// frame still wants tiles, [`upload_all`](Self::upload_all) and `select` again),
/// then [`draw`](Self::draw) after the frame's streaming; at the end
/// [`summary`](Self::summary).
pub trait FrameDrawer {
    /// Uploads what the open preloaded before the flight's clock starts, level by
    /// level (each pass can only want the children of what is already up), so that
    /// frame 0 draws.
    fn upload_preloaded(
        &mut self,
        selector: &mut Selector,
        camera: &Camera,
        pool: &TilePool,
        t: f64,
    );

    /// Whether frame `frame` waits for its selection to converge before it is drawn.
    fn settles(&self, frame: u32) -> bool;

    /// Selects at flight time `t` among the tiles that can be drawn (decoded and
    /// uploaded).
    fn select(
        &self,
        selector: &mut Selector,
        camera: &Camera,
        pool: &TilePool,
        t: f64,
    ) -> Selection;

    /// Uploads what `wanted` asks for, without a time budget; the tiles uploaded.
    fn upload_all(&mut self, pool: &TilePool, wanted: &[Wanted]) -> u32;

    /// Draws frame `frame` of `sel` (fetching what a measurement needs beyond it,
    /// and the drawn tiles' imagery; all of it before drawing when `settle`).
    fn draw(
        &mut self,
        frame: u32,
        camera: &Camera,
        sel: &Selection,
        pool: &mut TilePool,
        streamer: &mut Streamer,
        settle: bool,
    ) -> anyhow::Result<RenderRecord>;

    /// The flight's rendering totals over the frames drawn.
    fn summary(&self, rendered: &[(FrameStats, RenderRecord)]) -> RenderSummary;
}

/// Rendering figures of one frame (flattened into `stats.jsonl`).
#[derive(Clone, Copy, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct RenderRecord {
    pub draw_calls: u32,
    /// Tiles uploaded to the GPU this frame, and the time it took.
    pub uploads: u32,
    pub upload_ms: f64,
    pub render_ms: f64,
    /// Tiles holding a GPU slot.
    pub gpu_tiles: usize,
    /// Selection wants nothing it does not have: what is drawn is what the policy
    /// asks for (not an ancestor standing in).
    pub converged: bool,
    /// With `--quality`: against the full-resolution reference.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub mse: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub psnr: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub crack_pixels: Option<usize>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub reference_triangles: Option<u64>,
    /// With `--popping`: whether the selection differs from the previous frame's
    /// (tiles or LODs; `null` for the first frame).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub selection_changed: Option<bool>,
}

/// Rendering totals of a flight.
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct RenderSummary {
    pub gpu: String,
    pub median_triangles: u64,
    pub max_draw_calls: u32,
    pub median_select_ms: f64,
    pub median_upload_ms: f64,
    pub median_render_ms: f64,
    /// With `--quality`, over the measured frames that draw what the policy asks
    /// for (nothing wanted): while coarser tiles stand in, the image differs from
    /// the reference by design, and a coarse silhouette is not a crack.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub quality_frames: Option<usize>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub median_psnr: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub median_mse: Option<f64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub total_crack_pixels: Option<usize>,
    /// With `--popping`: per-pixel change between consecutive frames, where the
    /// selection changed and where it did not.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub popping: Option<crate::flight_report::popping::PoppingSummary>,
}

/// The median (0 for no values).
fn median(v: &[f64]) -> f64 {
    tessera_charts::stats::median(v).unwrap_or(0.0)
}

impl RenderSummary {
    /// The totals of `recs`, the frames a flight drew, on the GPU `gpu`.
    pub fn from_records(gpu: String, recs: &[(FrameStats, RenderRecord)]) -> Self {
        let quality: Vec<&RenderRecord> = recs
            .iter()
            .filter(|(s, r)| r.mse.is_some() && s.tiles > 0 && r.converged)
            .map(|(_, r)| r)
            .collect();
        let measured = recs.iter().any(|(_, r)| r.mse.is_some());
        let mut tris: Vec<u64> = recs.iter().map(|(s, _)| s.triangles).collect();
        tris.sort_unstable();
        Self {
            gpu,
            median_triangles: tris.get(tris.len() / 2).copied().unwrap_or(0),
            max_draw_calls: recs.iter().map(|(_, r)| r.draw_calls).max().unwrap_or(0),
            median_select_ms: median(
                &recs
                    .iter()
                    .map(|(s, _)| s.select_us / 1e3)
                    .collect::<Vec<_>>(),
            ),
            median_upload_ms: median(&recs.iter().map(|(_, r)| r.upload_ms).collect::<Vec<_>>()),
            median_render_ms: median(&recs.iter().map(|(_, r)| r.render_ms).collect::<Vec<_>>()),
            quality_frames: measured.then_some(quality.len()),
            median_psnr: measured
                .then(|| median(&quality.iter().filter_map(|r| r.psnr).collect::<Vec<_>>())),
            median_mse: measured
                .then(|| median(&quality.iter().filter_map(|r| r.mse).collect::<Vec<_>>())),
            total_crack_pixels: measured
                .then(|| quality.iter().filter_map(|r| r.crack_pixels).sum()),
            popping: None,
        }
    }
}
