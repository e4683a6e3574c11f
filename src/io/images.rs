//! Camera images in: EXR (a channel `I`, `Y`, or the mean of `R`, `G`, `B`), PNG and TIFF (8- or
//! 16-bit grey or RGB, 32-bit float TIFF), told apart by their first bytes, not by their names.
//! Colour images become the mean of their colour channels; alpha is ignored.

use std::path::Path;

pub use crate::inverse::phase_from_speckle::Image;

fn bad(path: &Path, what: impl std::fmt::Display) -> crate::Error {
    crate::Error::input(format!("{}: {what}", path.display()))
}

/// Read an image, naming the file in every error; refuses non-finite or negative pixels.
pub fn read_image(path: &Path) -> crate::Result<Image> {
    let bytes = std::fs::read(path).map_err(|e| bad(path, format!("cannot read: {e}")))?;
    let image = if bytes.starts_with(b"\x89PNG\r\n\x1a\n") {
        read_png(path, &bytes)?
    } else if bytes.starts_with(b"II*\0") || bytes.starts_with(b"MM\0*") {
        read_tiff(path, &bytes)?
    } else if bytes.starts_with(&[0x76, 0x2f, 0x31, 0x01]) {
        read_exr(path)?
    } else {
        return Err(bad(
            path,
            "not an image this build reads (EXR, PNG or TIFF, recognised by their first bytes)",
        ));
    };
    if image.width == 0 || image.height == 0 {
        return Err(bad(path, "the image is empty"));
    }
    if let Some(i) = image.data.iter().position(|v| !v.is_finite()) {
        return Err(bad(
            path,
            format!(
                "pixel ({}, {}) is not a finite number",
                i % image.width,
                i / image.width
            ),
        ));
    }
    if let Some(i) = image.data.iter().position(|v| *v < 0.0) {
        return Err(bad(
            path,
            format!(
                "pixel ({}, {}) is negative ({}); an intensity must be >= 0",
                i % image.width,
                i / image.width,
                image.data[i]
            ),
        ));
    }
    Ok(image)
}

/// Average `channels` consecutive samples per pixel (the first `colour` of them), to grey.
fn to_grey(samples: impl Iterator<Item = f64>, channels: usize, colour: usize) -> Vec<f64> {
    let v: Vec<f64> = samples.collect();
    v.chunks(channels)
        .map(|p| p[..colour].iter().sum::<f64>() / colour as f64)
        .collect()
}

fn read_png(path: &Path, bytes: &[u8]) -> crate::Result<Image> {
    let decoder = png::Decoder::new(bytes);
    let mut reader = decoder
        .read_info()
        .map_err(|e| bad(path, format!("not a readable PNG: {e}")))?;
    let mut buf = vec![0; reader.output_buffer_size()];
    let info = reader
        .next_frame(&mut buf)
        .map_err(|e| bad(path, format!("not a readable PNG: {e}")))?;
    let (channels, colour) = match info.color_type {
        png::ColorType::Grayscale => (1, 1),
        png::ColorType::GrayscaleAlpha => (2, 1),
        png::ColorType::Rgb => (3, 3),
        png::ColorType::Rgba => (4, 3),
        png::ColorType::Indexed => {
            return Err(bad(
                path,
                "a palette PNG; save camera frames as grey or RGB",
            ));
        }
    };
    let buf = &buf[..info.buffer_size()];
    let (data, full) = match info.bit_depth {
        png::BitDepth::Sixteen => (
            to_grey(
                buf.chunks(2)
                    .map(|b| u16::from_be_bytes([b[0], b[1]]) as f64),
                channels,
                colour,
            ),
            65535.0,
        ),
        png::BitDepth::Eight => (
            to_grey(buf.iter().map(|&b| b as f64), channels, colour),
            255.0,
        ),
        d => {
            return Err(bad(
                path,
                format!("{d:?}-bit PNG; camera frames must be 8 or 16 bits"),
            ));
        }
    };
    Ok(Image {
        width: info.width as usize,
        height: info.height as usize,
        data,
        full_scale: Some(full),
    })
}

fn read_tiff(path: &Path, bytes: &[u8]) -> crate::Result<Image> {
    use tiff::decoder::{Decoder, DecodingResult};
    let mut d = Decoder::new(std::io::Cursor::new(bytes))
        .map_err(|e| bad(path, format!("not a readable TIFF: {e}")))?;
    let (w, h) = d
        .dimensions()
        .map_err(|e| bad(path, format!("not a readable TIFF: {e}")))?;
    let colour = d
        .colortype()
        .map_err(|e| bad(path, format!("not a readable TIFF: {e}")))?;
    let (channels, colour) = match colour {
        tiff::ColorType::Gray(_) => (1, 1),
        tiff::ColorType::GrayA(_) => (2, 1),
        tiff::ColorType::RGB(_) => (3, 3),
        tiff::ColorType::RGBA(_) => (4, 3),
        other => {
            return Err(bad(
                path,
                format!("TIFF colour type {other:?}; camera frames must be grey or RGB"),
            ));
        }
    };
    let image = d
        .read_image()
        .map_err(|e| bad(path, format!("not a readable TIFF: {e}")))?;
    let (data, full) = match image {
        DecodingResult::U8(v) => (
            to_grey(v.into_iter().map(f64::from), channels, colour),
            Some(255.0),
        ),
        DecodingResult::U16(v) => (
            to_grey(v.into_iter().map(f64::from), channels, colour),
            Some(65535.0),
        ),
        DecodingResult::U32(v) => (
            to_grey(v.into_iter().map(f64::from), channels, colour),
            Some(u32::MAX as f64),
        ),
        DecodingResult::F32(v) => (
            to_grey(v.into_iter().map(f64::from), channels, colour),
            None,
        ),
        DecodingResult::F64(v) => (to_grey(v.into_iter(), channels, colour), None),
        _ => {
            return Err(bad(
                path,
                "TIFF sample format not supported; use 8/16-bit integer or float samples",
            ));
        }
    };
    Ok(Image {
        width: w as usize,
        height: h as usize,
        data,
        full_scale: full,
    })
}

fn read_exr(path: &Path) -> crate::Result<self::Image> {
    use exr::prelude::*;
    let image = read()
        .no_deep_data()
        .largest_resolution_level()
        .all_channels()
        .first_valid_layer()
        .all_attributes()
        .from_file(path)
        .map_err(|e| bad(path, format!("not a readable EXR: {e}")))?;
    let layer = &image.layer_data;
    let size = layer.size;
    let channels = &layer.channel_data.list;
    let find = |name: &str| channels.iter().find(|c| c.name.to_string() == name);
    let chosen: Vec<&AnyChannel<FlatSamples>> = if let Some(c) = find("I").or_else(|| find("Y")) {
        vec![c]
    } else if let (Some(r), Some(g), Some(b)) = (find("R"), find("G"), find("B")) {
        vec![r, g, b]
    } else {
        let names: Vec<String> = channels.iter().map(|c| c.name.to_string()).collect();
        return Err(bad(
            path,
            format!("EXR channels {names:?}: need an intensity channel I or Y, or R, G and B"),
        ));
    };
    let n = size.0 * size.1;
    let mut data = vec![0.0; n];
    for c in &chosen {
        for (i, v) in c.sample_data.values_as_f32().enumerate().take(n) {
            data[i] += v as f64 / chosen.len() as f64;
        }
    }
    Ok(self::Image {
        width: size.0,
        height: size.1,
        data,
        full_scale: None,
    })
}
