//! Input and output: config schema and validation, shard state files, JSON results, EXR images and
//! PNG plots.

pub mod config;
pub mod design_config;
pub mod exr;
pub mod plot;
pub mod state;
pub mod trace_config;

pub use config::{Config, ConfigError};
pub use state::write_atomic;

/// Serialise `value` as JSON to `path` atomically.
pub fn write_json(path: &std::path::Path, value: &serde_json::Value) -> std::io::Result<()> {
    let text = serde_json::to_vec(value).map_err(std::io::Error::other)?;
    write_atomic(path, &text)
}

/// Image shape for `views` fields: the pixel grid when the config's only view is a grid, else a row.
pub fn image_shape(cfg: &Config, views: usize) -> (usize, usize) {
    match cfg.view.as_slice() {
        [config::ViewConfig::FarFieldGrid { pixels, .. }] => {
            (pixels[0] as usize, pixels[1] as usize)
        }
        _ => (views, 1),
    }
}
