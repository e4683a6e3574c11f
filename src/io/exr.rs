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
    use exr::prelude::*;
    let views = width * height;
    let mut files = Vec::new();
    let stem = path
        .file_stem()
        .and_then(|s| s.to_str())
        .unwrap_or("speckle");
    for l in 0..lights {
        let file = path.with_file_name(format!("{stem}_l{l}.exr"));
        let field = &u[l * views..(l + 1) * views];
        let pixels = SpecificChannels::build()
            .with_channel("I")
            .with_channel("im")
            .with_channel("re")
            .with_pixel_fn(|p: Vec2<usize>| {
                let z = field[p.y() * width + p.x()];
                (z.norm_sqr() as f32, z.im as f32, z.re as f32)
            });
        let mut bytes = std::io::Cursor::new(Vec::new());
        Image::from_channels((width, height), pixels)
            .write()
            .to_buffered(&mut bytes)
            .map_err(|e| crate::Error::input(format!("{}: {e}", file.display())))?;
        write_file(&file, bytes.get_ref())?;
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
    use exr::prelude::*;
    let pixels = SpecificChannels::build()
        .with_channel(name)
        .with_pixel_fn(|p: Vec2<usize>| (values[p.y() * width + p.x()] as f32,));
    let mut bytes = std::io::Cursor::new(Vec::new());
    Image::from_channels((width, height), pixels)
        .write()
        .to_buffered(&mut bytes)
        .map_err(|e| crate::Error::input(format!("{}: {e}", path.display())))?;
    write_file(path, bytes.get_ref())
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
    use exr::prelude::*;
    let pixels = SpecificChannels::build()
        .with_channel("Y")
        .with_channel("stderr")
        .with_pixel_fn(|p: Vec2<usize>| {
            let i = p.y() * width + p.x();
            (values[i] as f32, stderr[i] as f32)
        });
    let mut bytes = std::io::Cursor::new(Vec::new());
    Image::from_channels((width, height), pixels)
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
