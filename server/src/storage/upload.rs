//! `build … -o s3://…`: a finished, verified local pyramid goes to its object with a
//! multipart upload that is completed only when every part is in, and aborted
//! otherwise, so the key never names a partial pyramid
//! (docs/ARCHITECTURE.md#nothing-partial).

use super::location::{self, ObjectLocation};
use object_store::{ObjectStoreExt, WriteMultipart};
use std::io::Read;
use std::path::Path;

/// Parts of 16 MiB (S3 wants at least 5 MiB but the last), four in flight.
const PART: usize = 16 << 20;
const IN_FLIGHT: usize = 4;

/// Uploads `local` to `to`; the object's size afterwards, checked against the file's.
/// `progress` is told the bytes handed to the upload so far.
pub fn upload_file(
    local: &Path,
    to: &ObjectLocation,
    progress: impl Fn(u64) + Send + Sync + 'static,
) -> anyhow::Result<u64> {
    let local = local.to_path_buf();
    let to = to.clone();
    super::runtime::block_on(async move {
        let size = std::fs::metadata(&local)
            .map_err(|e| anyhow::anyhow!("{}: {e}", local.display()))?
            .len();
        let upload = to
            .store
            .put_multipart(&to.key)
            .await
            .map_err(|e| anyhow::anyhow!("{}: cannot start the upload: {e}", to.url))?;
        let mut writer = WriteMultipart::new_with_chunk_size(upload, PART);
        let sent = copy_parts(&local, &mut writer, &progress).await;
        if let Err(e) = sent {
            // Abort so the store frees the parts; the key never appears.
            if let Err(abort) = writer.abort().await {
                tracing::warn!(url = %to.url, "aborting the failed upload failed too: {abort}");
            }
            return Err(e.context(format!("{}: upload failed; nothing was written", to.url)));
        }
        writer
            .finish()
            .await
            .map_err(|e| anyhow::anyhow!("{}: completing the upload failed: {e}", to.url))?;
        let meta =
            to.store.head(&to.key).await.map_err(|e| {
                anyhow::anyhow!("{}: cannot check the uploaded object: {e}", to.url)
            })?;
        anyhow::ensure!(
            meta.size == size,
            "{}: the store holds {} bytes after the upload, the pyramid has {size}",
            to.url,
            meta.size
        );
        Ok(size)
    })
}

async fn copy_parts(
    local: &Path,
    writer: &mut WriteMultipart,
    progress: &(impl Fn(u64) + Send + Sync),
) -> anyhow::Result<()> {
    let mut file =
        std::fs::File::open(local).map_err(|e| anyhow::anyhow!("{}: {e}", local.display()))?;
    let mut buf = vec![0u8; PART];
    let mut total = 0u64;
    loop {
        writer
            .wait_for_capacity(IN_FLIGHT)
            .await
            .map_err(|e| anyhow::anyhow!("a part failed: {e}"))?;
        let n = read_full(&mut file, &mut buf)
            .map_err(|e| anyhow::anyhow!("{}: {e}", local.display()))?;
        if n == 0 {
            return Ok(());
        }
        writer.write(&buf[..n]);
        total += n as u64;
        progress(total);
    }
}

/// Fills `buf` unless the file ends first; the bytes read.
fn read_full(file: &mut std::fs::File, buf: &mut [u8]) -> std::io::Result<usize> {
    let mut n = 0;
    while n < buf.len() {
        match file.read(&mut buf[n..])? {
            0 => break,
            k => n += k,
        }
    }
    Ok(n)
}

/// Runs `build` with the local path it is to write: `output` itself, or for an
/// object URL (`s3://…`) a file in a fresh temporary directory (under `TMPDIR`),
/// uploaded to the object once `build` has finished and verified it. Returns what
/// `build` returned. A failed build or upload leaves no object and no local file.
pub fn with_output<R>(
    output: &Path,
    progress: bool,
    build: impl FnOnce(&Path) -> anyhow::Result<R>,
) -> anyhow::Result<R> {
    with_output_of_kind(output, "tess", progress, build)
}

/// [`with_output`] for a file whose objects' keys end in `.{extension}`.
pub fn with_output_of_kind<R>(
    output: &Path,
    extension: &str,
    progress: bool,
    build: impl FnOnce(&Path) -> anyhow::Result<R>,
) -> anyhow::Result<R> {
    let raw = output.to_string_lossy();
    let location::Location::Object(object) =
        location::locate_kind(&raw, location::StoreOptions::default(), extension)?
    else {
        return build(output);
    };
    let dir = tempfile::Builder::new()
        .prefix("tessera-upload-")
        .tempdir()
        .map_err(|e| anyhow::anyhow!("cannot make a temporary directory for {raw}: {e}"))?;
    let local = dir.path().join(object.key.filename().unwrap_or("output"));
    let result = build(&local)?;
    let size = std::fs::metadata(&local).map_or(0, |m| m.len());
    let bar = if progress {
        indicatif::ProgressBar::new(size).with_style(
            indicatif::ProgressStyle::with_template(
                "{msg:>10} [{bar:40}] {bytes}/{total_bytes} {bytes_per_sec} eta {eta}",
            )
            .expect("static template")
            .progress_chars("=> "),
        )
    } else {
        indicatif::ProgressBar::hidden()
    };
    bar.set_message("uploading");
    let shown = bar.clone();
    let uploaded = upload_file(&local, &object, move |n| shown.set_position(n));
    bar.finish_and_clear();
    let bytes = uploaded?;
    tracing::info!(url = %object.url, bytes, "uploaded");
    Ok(result)
}
