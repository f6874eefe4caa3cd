//! A dataset's imagery (DECISIONS.md "Imagery pyramids"): the `NAME.tessimg` beside
//! `NAME.tess`, attached when it was built for exactly that DEM (FORMAT.md "Imagery
//! pyramids").

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
    Ok(attach(ds, imagery))
}

/// The imagery object beside a DEM pyramid in object storage (`s3://b/dem.tessimg`
/// beside `s3://b/dem.tess`), by the same rules as [`open_beside`]: no object, no
/// imagery; an object that does not open, an error. Its reads share the store's
/// block cache.
pub fn open_beside_object(
    ds: &Dataset,
    loc: crate::storage::ObjectLocation,
    ctx: &Arc<crate::storage::StoreContext>,
) -> anyhow::Result<Option<Arc<Dataset>>> {
    let label = std::path::PathBuf::from(&loc.url);
    let storage = match crate::storage::ObjectStorage::open(loc, ctx.clone()) {
        Ok(s) => s,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
        Err(e) => return Err(e.into()),
    };
    let imagery = Dataset::imagery_from_storage(ds.name.clone(), label, Arc::new(storage))?;
    Ok(attach(ds, imagery))
}

/// `imagery` for `ds` when it was built for exactly this DEM (its content hash);
/// otherwise `None`, with a warning.
fn attach(ds: &Dataset, imagery: Dataset) -> Option<Arc<Dataset>> {
    let built_for = &imagery
        .pyramid
        .imagery()
        .expect("opened as imagery")
        .dem
        .content_hash;
    if built_for != ds.content_hash() {
        tracing::warn!(
            dataset = %ds.name,
            imagery = %imagery.path.display(),
            built_for = %built_for,
            dem = %ds.content_hash(),
            "ignoring imagery built for another version of the DEM"
        );
        return None;
    }
    tracing::info!(dataset = %ds.name, imagery = %imagery.path.display(), "serving imagery");
    Some(Arc::new(imagery))
}
