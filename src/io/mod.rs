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
