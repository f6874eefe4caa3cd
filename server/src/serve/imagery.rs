//! A dataset's imagery (issue 17 item 5): the `NAME.tessimg` beside `NAME.tess`,
//! attached when it was built for exactly that DEM (FORMAT.md "Imagery pyramids").

use super::dataset::Dataset;
use std::path::Path;
use std::sync::Arc;

/// The imagery pyramid beside the local DEM pyramid `dem` of `ds`: `None` when there
/// is none, or (with a warning) when it belongs to another DEM — a stale file left by
/// an earlier build, which must not be draped on this one. A file that is there but
/// does not open is an error, as a damaged `.tess` is.
pub fn open_beside(ds: &Dataset, dem: &Path) -> anyhow::Result<Option<Arc<Dataset>>> {
    let path = crate::imagery::sibling_path(dem);
    if !path.is_file() {
        return Ok(None);
    }
    let imagery = Dataset::open_imagery(ds.name.clone(), &path)?;
    let built_for = &imagery
        .pyramid
        .imagery()
        .expect("opened as imagery")
        .dem
        .content_hash;
    if built_for != ds.content_hash() {
        tracing::warn!(
            dataset = %ds.name,
            imagery = %path.display(),
            built_for = %built_for,
            dem = %ds.content_hash(),
            "ignoring imagery built for another version of the DEM"
        );
        return Ok(None);
    }
    tracing::info!(dataset = %ds.name, imagery = %path.display(), "serving imagery");
    Ok(Some(Arc::new(imagery)))
}
