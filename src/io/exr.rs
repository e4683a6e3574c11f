//! EXR output of speckle fields: one file per realisation and light, channels `re`, `im` and the
//! intensity `I = |u|²`, as 32-bit floats.

use crate::math::C64;
use std::path::Path;

/// Write the fields `u[l·V + v]` of every light as `width × height` images (views row-major).
/// File names: `<stem>_l<light>.exr` next to `path`.
pub fn write_fields(
    path: &Path,
    u: &[C64],
    lights: usize,
    width: usize,
    height: usize,
) -> crate::Result<Vec<std::path::PathBuf>> {
    let views = width * height;
    let mut files = Vec::new();
    let stem = path
        .file_stem()
        .and_then(|s| s.to_str())
        .unwrap_or("speckle");
    for l in 0..lights {
        let file = path.with_file_name(format!("{stem}_l{l}.exr"));
        let field = &u[l * views..(l + 1) * views];
        let re: Vec<f64> = field.iter().map(|z| z.re).collect();
        let im: Vec<f64> = field.iter().map(|z| z.im).collect();
        let intensity: Vec<f64> = field.iter().map(|z| z.norm_sqr()).collect();
        write_planes(
            &file,
            &[("I", &intensity), ("im", &im), ("re", &re)],
            width,
            height,
        )?;
        files.push(file);
    }
    Ok(files)
}

/// Write one scalar channel `name` as a `width × height` image (row-major `values`).
pub fn write_scalar(
    path: &Path,
    values: &[f64],
    width: usize,
    height: usize,
    name: &str,
) -> crate::Result<()> {
    write_planes(path, &[(name, values)], width, height)
}

/// Write a `width × height` image (row-major) with its per-pixel standard error: channels `Y`
/// (the value) and `stderr`.
pub fn write_with_error(
    path: &Path,
    values: &[f64],
    stderr: &[f64],
    width: usize,
    height: usize,
) -> crate::Result<()> {
    write_planes(path, &[("Y", values), ("stderr", stderr)], width, height)
}

/// Write named `width × height` planes (row-major, 32-bit float channels; rows from the bottom
/// as the values run) into one EXR file.
pub fn write_planes(
    path: &Path,
    planes: &[(&str, &[f64])],
    width: usize,
    height: usize,
) -> crate::Result<()> {
    use exr::prelude::*;
    let list = planes
        .iter()
        .map(|(name, v)| {
            let samples = (0..width * height).map(|i| v[i] as f32).collect();
            AnyChannel::new(*name, FlatSamples::F32(samples))
        })
        .collect::<Vec<_>>();
    let layer = Layer::new(
        (width, height),
        LayerAttributes::default(),
        Encoding::default(),
        AnyChannels::sort(SmallVec::from_vec(list)),
    );
    let mut bytes = std::io::Cursor::new(Vec::new());
    Image::from_layer(layer)
        .write()
        .to_buffered(&mut bytes)
        .map_err(|e| crate::Error::input(format!("{}: {e}", path.display())))?;
    write_file(path, bytes.get_ref())
}

/// Write an encoded image atomically.
fn write_file(path: &Path, bytes: &[u8]) -> crate::Result<()> {
    crate::io::write_atomic(path, bytes).map_err(|source| crate::Error::Io {
        action: "write",
        path: path.to_path_buf(),
        source,
    })
}
