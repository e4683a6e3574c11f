//! Input and output of results: typed result files, shard state files, EXR images and PNG plots.
//! (Configs are read by [`crate::config`].)

pub mod exr;
pub mod images;
pub mod plot;
pub mod results;
pub mod state;
pub mod targets;

pub use results::ResultFile;
pub use state::write_atomic;

/// Serialise `value` as JSON to `path` atomically.
pub fn write_json<T: serde::Serialize + ?Sized>(
    path: &std::path::Path,
    value: &T,
) -> std::io::Result<()> {
    let text = serde_json::to_vec(value).map_err(std::io::Error::other)?;
    write_atomic(path, &text)
}

/// The name a file is written under before it is renamed to `path`: hidden, in the same folder
/// (so the rename is atomic), with the same extension (so writers that pick the format by extension
/// still work). A run killed mid-write leaves only such a name, which the next run clears.
pub fn staging_name(path: &std::path::Path) -> std::path::PathBuf {
    let name = path
        .file_name()
        .map_or_else(|| "output".into(), |n| n.to_string_lossy().into_owned());
    path.with_file_name(format!("{STAGING_PREFIX}{name}"))
}

/// Prefix of [`staging_name`]s.
pub const STAGING_PREFIX: &str = ".partial-";

/// Move a file written under [`staging_name`] into place.
pub fn commit_staged(staged: &std::path::Path, path: &std::path::Path) -> crate::Result<()> {
    std::fs::rename(staged, path).map_err(|source| crate::Error::Io {
        action: "write",
        path: path.to_path_buf(),
        source,
    })
}

/// Image shape for `views` fields: the pixel grid when the config's only view is a grid, else a row.
pub fn image_shape(cfg: &crate::config::Config, views: usize) -> (usize, usize) {
    match cfg.view.as_slice() {
        [crate::config::ViewConfig::FarFieldGrid { pixels, .. }]
        | [crate::config::ViewConfig::FocusedGrid { pixels, .. }] => {
            (pixels[0] as usize, pixels[1] as usize)
        }
        _ => (views, 1),
    }
}
