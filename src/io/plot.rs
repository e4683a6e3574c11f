//! PNG plots (plotters with an embedded DejaVu font, so no system fonts are needed).

use crate::speckle::memory::{MemoryCurve, diffusion_correlation};
use plotters::prelude::*;
use std::path::Path;
use std::sync::Once;

/// The legend box every plot uses.
fn legend<'a, DB: DrawingBackend + 'a, CT: plotters::coord::CoordTranslate>(
    chart: &mut ChartContext<'a, DB, CT>,
    size: u32,
) -> crate::Result<()>
where
    DB::ErrorType: 'static,
{
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .label_font(("sans-serif", size))
        .draw()
        .map_err(|x| crate::Error::input(x.to_string()))
}

fn register_font() {
    static ONCE: Once = Once::new();
    ONCE.call_once(|| {
        let _ = plotters::style::register_font(
            "sans-serif",
            FontStyle::Normal,
            dejavu::sans::regular(),
        );
    });
}

/// Heat maps side by side, one per panel title, values in `[0, 1]` (row-major `ny × nx`, row 0 at
/// the bottom), with a grey scale from black (0) to white (1).
pub fn heat_maps(
    path: &Path,
    title: &str,
    panels: &[(String, Vec<f64>)],
    nx: usize,
    ny: usize,
) -> crate::Result<()> {
    let names: Vec<&str> = panels.iter().map(|(n, _)| n.as_str()).collect();
    pixel_panels(path, title, &names, nx, ny, |p, i| {
        let g = (255.0 * panels[p].1[i].clamp(0.0, 1.0)) as u8;
        RGBColor(g, g, g)
    })
}

/// One colour image, linear values in `[0, 1]` per channel (row-major `ny × nx`, row 0 at the
/// bottom), encoded with
/// the sRGB transfer curve.
pub fn colour_image(
    path: &Path,
    title: &str,
    name: &str,
    rgb: &[[f64; 3]],
    nx: usize,
    ny: usize,
) -> crate::Result<()> {
    let encode = |v: f64| {
        let v = v.clamp(0.0, 1.0);
        let s = if v <= 0.0031308 {
            12.92 * v
        } else {
            1.055 * v.powf(1.0 / 2.4) - 0.055
        };
        (255.0 * s).round() as u8
    };
    pixel_panels(path, title, &[name], nx, ny, |_, i| {
        let [r, g, b] = rgb[i].map(encode);
        RGBColor(r, g, b)
    })
}

/// Panels of `nx × ny` pixels side by side, pixel `i` of panel `p` coloured `colour(p, i)`; each
/// panel 260 pixels wide and as high as the image's aspect says (within a quarter and twice
/// that, so strips stay visible).
fn pixel_panels(
    path: &Path,
    title: &str,
    names: &[&str],
    nx: usize,
    ny: usize,
    colour: impl Fn(usize, usize) -> RGBColor,
) -> crate::Result<()> {
    register_font();
    let e = |e: &dyn std::fmt::Display| e.to_string();
    let side = 260u32;
    let aspect = (ny as f64 / nx.max(1) as f64).clamp(0.25, 2.0);
    // around each plot: the margins (8 on each side) and the caption; above them, the title
    let width = (side + 16) * names.len().max(1) as u32;
    let height = (side as f64 * aspect).round() as u32 + 16 + 22 + 32;
    let staged = crate::io::staging_name(path);
    let root = BitMapBackend::new(&staged, (width, height)).into_drawing_area();
    root.fill(&WHITE).map_err(|x| e(&x))?;
    let root = root.titled(title, ("sans-serif", 20)).map_err(|x| e(&x))?;
    let areas = root.split_evenly((1, names.len().max(1)));
    for (p, (name, area)) in names.iter().zip(areas).enumerate() {
        let mut chart = ChartBuilder::on(&area)
            .caption(*name, ("sans-serif", 15))
            .margin(8)
            .build_cartesian_2d(0..nx, 0..ny)
            .map_err(|x| e(&x))?;
        let colour = &colour;
        chart
            .draw_series((0..ny).flat_map(|y| {
                (0..nx).map(move |x| {
                    Rectangle::new([(x, y), (x + 1, y + 1)], colour(p, y * nx + x).filled())
                })
            }))
            .map_err(|x| e(&x))?;
    }
    root.present().map_err(|x| e(&x))?;
    crate::io::commit_staged(&staged, path)?;
    Ok(())
}

/// Memory-effect curve with error bars and the diffusion prediction (paper 001, Eq. 39).
pub fn memory_effect(path: &Path, c: &MemoryCurve) -> crate::Result<()> {
    register_font();
    let e = |e: &dyn std::fmt::Display| e.to_string();
    let staged = crate::io::staging_name(path);
    let root = BitMapBackend::new(&staged, (800, 560)).into_drawing_area();
    root.fill(&WHITE).map_err(|x| e(&x))?;
    let xmax = c.angles_deg.iter().fold(0.0f64, |a, &b| a.max(b.abs())) * 1.05;
    let xmax = if xmax > 0.0 { xmax } else { 1.0 };
    let mut chart = ChartBuilder::on(&root)
        .caption(
            "Memory effect: intensity correlation vs tilt",
            ("sans-serif", 22),
        )
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(60)
        .build_cartesian_2d(0.0..xmax, 0.0..1.05)
        .map_err(|x| e(&x))?;
    chart
        .configure_mesh()
        .x_desc("tilt angle θ [deg]")
        .y_desc("|C12|² / (C11 C22)")
        .label_style(("sans-serif", 15))
        .draw()
        .map_err(|x| e(&x))?;
    let theory: Vec<(f64, f64)> = (0..=200)
        .map(|i| {
            let a = xmax * i as f64 / 200.0;
            (a, diffusion_correlation(c.kl, a.to_radians()))
        })
        .collect();
    chart
        .draw_series(LineSeries::new(theory, BLUE.stroke_width(2)))
        .map_err(|x| e(&x))?
        .label("diffusion, Eq. 39")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLUE.stroke_width(2)));
    chart
        .draw_series(
            c.angles_deg
                .iter()
                .zip(&c.correlation)
                .zip(&c.stderr)
                .map(|((a, r), s)| {
                    ErrorBar::new_vertical(a.abs(), r - 2.0 * s, *r, r + 2.0 * s, RED.filled(), 6)
                }),
        )
        .map_err(|x| e(&x))?
        .label("Monte Carlo (±2 s.e.)")
        .legend(|(x, y)| Circle::new((x + 10, y), 4, RED.filled()));
    chart
        .draw_series(
            c.angles_deg
                .iter()
                .zip(&c.correlation)
                .map(|(a, r)| Circle::new((a.abs(), *r), 4, RED.filled())),
        )
        .map_err(|x| e(&x))?;
    legend(&mut chart, 15)?;
    root.present().map_err(|x| e(&x))?;
    crate::io::commit_staged(&staged, path)?;
    Ok(())
}

/// A perceptually ordered colour for `t ∈ [0, 1]` (five viridis anchors, linearly interpolated).
fn viridis(t: f64) -> RGBColor {
    const A: [(f64, f64, f64); 5] = [
        (68.0, 1.0, 84.0),
        (59.0, 82.0, 139.0),
        (33.0, 145.0, 140.0),
        (94.0, 201.0, 98.0),
        (253.0, 231.0, 37.0),
    ];
    let x = t.clamp(0.0, 1.0) * 4.0;
    let i = (x.floor() as usize).min(3);
    let f = x - i as f64;
    let lerp = |a: f64, b: f64| (a + (b - a) * f).round() as u8;
    RGBColor(
        lerp(A[i].0, A[i + 1].0),
        lerp(A[i].1, A[i + 1].1),
        lerp(A[i].2, A[i + 1].2),
    )
}

/// One light pair's `[v1][v2]` covariance block from two runs, for side-by-side plots.
pub struct PairBlock {
    pub label: String,
    /// `|C|` of A and B, row-major `nv × nv`.
    pub a: Vec<f64>,
    pub b: Vec<f64>,
    /// Diagonal (`v1 = v2`) real parts and standard errors of A and B.
    pub diag_a: Vec<(f64, f64)>,
    pub diag_b: Vec<(f64, f64)>,
}

/// `compare --plot`: diagonals with ±2 s.e. bars (one panel per light pair) and `|C|` matrices of
/// A and B side by side.
pub fn compare(
    dir: &Path,
    names: (&str, &str),
    pairs: &[PairBlock],
    nv: usize,
) -> crate::Result<Vec<std::path::PathBuf>> {
    register_font();
    let e = |e: &dyn std::fmt::Display| e.to_string();
    let cols = (pairs.len() as f64).sqrt().ceil() as usize;
    let rows = pairs.len().div_ceil(cols);
    let diag_path = dir.join("compare_diagonals.png");
    {
        let staged = crate::io::staging_name(&diag_path);
        let root =
            BitMapBackend::new(&staged, (520 * cols as u32, 380 * rows as u32)).into_drawing_area();
        root.fill(&WHITE).map_err(|x| e(&x))?;
        for (p, area) in pairs.iter().zip(root.split_evenly((rows, cols))) {
            let lo = p
                .diag_a
                .iter()
                .chain(&p.diag_b)
                .map(|(v, s)| v - 2.0 * s)
                .fold(f64::INFINITY, f64::min)
                .min(0.0);
            let hi = p
                .diag_a
                .iter()
                .chain(&p.diag_b)
                .map(|(v, s)| v + 2.0 * s)
                .fold(f64::NEG_INFINITY, f64::max);
            let hi = if hi > lo { hi } else { lo + 1.0 };
            let mut chart = ChartBuilder::on(&area)
                .caption(
                    format!("Re C[v][v], lights {}", p.label),
                    ("sans-serif", 18),
                )
                .margin(10)
                .x_label_area_size(35)
                .y_label_area_size(55)
                .build_cartesian_2d(-0.5..(nv as f64 - 0.5), lo..hi * 1.05)
                .map_err(|x| e(&x))?;
            chart
                .configure_mesh()
                .x_desc("view")
                .label_style(("sans-serif", 13))
                .draw()
                .map_err(|x| e(&x))?;
            for (data, colour, name, off) in [
                (&p.diag_a, RED, names.0, -0.12),
                (&p.diag_b, BLUE, names.1, 0.12),
            ] {
                chart
                    .draw_series(data.iter().enumerate().map(|(v, (m, s))| {
                        ErrorBar::new_vertical(
                            v as f64 + off,
                            m - 2.0 * s,
                            *m,
                            m + 2.0 * s,
                            colour.filled(),
                            4,
                        )
                    }))
                    .map_err(|x| e(&x))?
                    .label(name)
                    .legend(move |(x, y)| Circle::new((x + 10, y), 4, colour.filled()));
            }
            legend(&mut chart, 13)?;
        }
        root.present().map_err(|x| e(&x))?;
        crate::io::commit_staged(&staged, &diag_path)?;
    }
    let mat_path = dir.join("compare_matrices.png");
    {
        let cell = (360 / nv.max(1)).max(1) as u32;
        let side = cell * nv as u32;
        let staged = crate::io::staging_name(&mat_path);
        let root = BitMapBackend::new(&staged, (2 * side + 60, (side + 40) * pairs.len() as u32))
            .into_drawing_area();
        root.fill(&WHITE).map_err(|x| e(&x))?;
        for (row, p) in root.split_evenly((pairs.len(), 1)).iter().zip(pairs) {
            let max =
                p.a.iter()
                    .chain(&p.b)
                    .cloned()
                    .fold(0.0f64, f64::max)
                    .max(1e-300);
            let (left, right) = row.split_horizontally(side + 30);
            for (area, data, name) in [(left, &p.a, names.0), (right, &p.b, names.1)] {
                area.draw(&Text::new(
                    format!("|C| {name}, lights {}", p.label),
                    (5, 5),
                    ("sans-serif", 14),
                ))
                .map_err(|x| e(&x))?;
                for v1 in 0..nv {
                    for v2 in 0..nv {
                        let t = (data[v1 * nv + v2] / max).clamp(0.0, 1.0);
                        let c = viridis(t);
                        let (x, y) = (v2 as i32 * cell as i32 + 5, v1 as i32 * cell as i32 + 25);
                        area.draw(&Rectangle::new(
                            [(x, y), (x + cell as i32, y + cell as i32)],
                            c.filled(),
                        ))
                        .map_err(|x| e(&x))?;
                    }
                }
            }
        }
        root.present().map_err(|x| e(&x))?;
        crate::io::commit_staged(&staged, &mat_path)?;
    }
    Ok(vec![diag_path, mat_path])
}

/// Fit of a memory-effect curve: target (with ±2 s.e. bars when given), initial and fitted model.
pub fn fit_curve(
    path: &Path,
    angles: &[f64],
    target: &[f64],
    stderr: Option<&[f64]>,
    initial: &[f64],
    fitted: &[f64],
) -> crate::Result<()> {
    register_font();
    let e = |e: &dyn std::fmt::Display| e.to_string();
    let staged = crate::io::staging_name(path);
    let root = BitMapBackend::new(&staged, (800, 560)).into_drawing_area();
    root.fill(&WHITE).map_err(|x| e(&x))?;
    let xmax = angles.iter().fold(0.0f64, |a, b| a.max(b.abs())) * 1.05;
    let ymax = target
        .iter()
        .chain(initial)
        .chain(fitted)
        .fold(1.0f64, |a, b| a.max(*b))
        * 1.05;
    let mut chart = ChartBuilder::on(&root)
        .caption("Fit: memory-effect correlation", ("sans-serif", 22))
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(60)
        .build_cartesian_2d(0.0..xmax.max(1e-9), 0.0..ymax)
        .map_err(|x| e(&x))?;
    chart
        .configure_mesh()
        .x_desc("tilt angle θ [deg]")
        .y_desc("|C12|² / (C11 C22)")
        .label_style(("sans-serif", 15))
        .draw()
        .map_err(|x| e(&x))?;
    let line = |v: &[f64]| -> Vec<(f64, f64)> {
        let mut p: Vec<(f64, f64)> = angles
            .iter()
            .map(|a| a.abs())
            .zip(v.iter().copied())
            .collect();
        p.sort_by(|a, b| a.0.total_cmp(&b.0));
        p
    };
    chart
        .draw_series(LineSeries::new(
            line(initial),
            BLACK.mix(0.5).stroke_width(2),
        ))
        .map_err(|x| e(&x))?
        .label("initial")
        .legend(|(x, y)| {
            PathElement::new(vec![(x, y), (x + 20, y)], BLACK.mix(0.5).stroke_width(2))
        });
    chart
        .draw_series(LineSeries::new(line(fitted), BLUE.stroke_width(2)))
        .map_err(|x| e(&x))?
        .label("fitted")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLUE.stroke_width(2)));
    chart
        .draw_series(angles.iter().zip(target).enumerate().map(|(i, (a, t))| {
            let s = stderr.map_or(0.0, |s| s[i]);
            ErrorBar::new_vertical(a.abs(), t - 2.0 * s, *t, t + 2.0 * s, RED.filled(), 6)
        }))
        .map_err(|x| e(&x))?
        .label("target")
        .legend(|(x, y)| Circle::new((x + 10, y), 4, RED.filled()));
    legend(&mut chart, 15)?;
    root.present().map_err(|x| e(&x))?;
    crate::io::commit_staged(&staged, path)?;
    Ok(())
}

/// Ray paths projected on the x-z plane.
pub fn ray_paths(path: &Path, rays: &[Vec<glam::DVec3>]) -> crate::Result<()> {
    register_font();
    let e = |e: &dyn std::fmt::Display| e.to_string();
    let pts = rays.iter().flatten();
    let (mut x0, mut x1, mut z0, mut z1) = (
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
    );
    for p in pts {
        x0 = x0.min(p.x);
        x1 = x1.max(p.x);
        z0 = z0.min(p.z);
        z1 = z1.max(p.z);
    }
    if !(x0.is_finite() && z0.is_finite()) {
        return Err("no ray points to draw".into());
    }
    let pad = 0.05 * (x1 - x0).max(z1 - z0).max(1e-9);
    let staged = crate::io::staging_name(path);
    let root = BitMapBackend::new(&staged, (800, 600)).into_drawing_area();
    root.fill(&WHITE).map_err(|x| e(&x))?;
    let mut chart = ChartBuilder::on(&root)
        .caption("Ray paths (x-z projection)", ("sans-serif", 20))
        .margin(15)
        .x_label_area_size(40)
        .y_label_area_size(50)
        .build_cartesian_2d((z0 - pad)..(z1 + pad), (x0 - pad)..(x1 + pad))
        .map_err(|x| e(&x))?;
    chart
        .configure_mesh()
        .x_desc("z")
        .y_desc("x")
        .label_style(("sans-serif", 14))
        .draw()
        .map_err(|x| e(&x))?;
    for r in rays {
        chart
            .draw_series(LineSeries::new(r.iter().map(|p| (p.z, p.x)), BLUE.mix(0.7)))
            .map_err(|x| e(&x))?;
    }
    root.present().map_err(|x| e(&x))?;
    crate::io::commit_staged(&staged, path)?;
    Ok(())
}

/// A fitted phase function: `ρ` at the table's nodes (log scale) — initial, fitted with ±1 sd
/// bars — and, where the scene allows it, the single-scattering readings of paper 004 per
/// illumination displacement `Δ`.
pub fn phase_fit(
    path: &Path,
    angles_deg: &[f64],
    initial: &[f64],
    fitted: &[f64],
    stddev: &[f64],
    readings: &[crate::inverse::shortcut::Reading],
) -> crate::Result<()> {
    register_font();
    let e = |e: &dyn std::fmt::Display| e.to_string();
    let staged = crate::io::staging_name(path);
    let root = BitMapBackend::new(&staged, (900, 600)).into_drawing_area();
    root.fill(&WHITE).map_err(|x| e(&x))?;
    let positive = |v: f64| v.is_finite() && v > 0.0;
    let all = initial
        .iter()
        .chain(fitted)
        .copied()
        .chain(readings.iter().map(|r| r.rho))
        .filter(|v| positive(*v));
    let (lo, hi) = all.fold((f64::INFINITY, 0.0f64), |(a, b), v| (a.min(v), b.max(v)));
    if !(positive(lo) && positive(hi)) {
        return Err("phase_fit: nothing positive to plot".into());
    }
    let mut chart = ChartBuilder::on(&root)
        .caption(
            "Phase function: fit and single-scattering reading",
            ("sans-serif", 22),
        )
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(70)
        .build_cartesian_2d(0.0..180.0, (lo / 2.0..hi * 2.0).log_scale())
        .map_err(|x| e(&x))?;
    chart
        .configure_mesh()
        .x_desc("scattering angle θ [deg]")
        .y_desc("ρ(θ) [1/sr]")
        .label_style(("sans-serif", 15))
        .draw()
        .map_err(|x| e(&x))?;
    let curve = |v: &[f64]| -> Vec<(f64, f64)> {
        let mut p: Vec<(f64, f64)> = angles_deg.iter().copied().zip(v.iter().copied()).collect();
        p.sort_by(|a, b| a.0.total_cmp(&b.0));
        p
    };
    chart
        .draw_series(LineSeries::new(
            curve(initial),
            BLACK.mix(0.5).stroke_width(2),
        ))
        .map_err(|x| e(&x))?
        .label("initial")
        .legend(|(x, y)| {
            PathElement::new(vec![(x, y), (x + 20, y)], BLACK.mix(0.5).stroke_width(2))
        });
    chart
        .draw_series(LineSeries::new(curve(fitted), BLUE.stroke_width(2)))
        .map_err(|x| e(&x))?
        .label("fitted (±1 sd)")
        .legend(|(x, y)| PathElement::new(vec![(x, y), (x + 20, y)], BLUE.stroke_width(2)));
    chart
        .draw_series(
            angles_deg
                .iter()
                .zip(fitted.iter().zip(stddev))
                .map(|(a, (v, s))| {
                    let low = (v - s).max(v / 10.0);
                    ErrorBar::new_vertical(*a, low, *v, v + s, BLUE.filled(), 6)
                }),
        )
        .map_err(|x| e(&x))?;
    let mut deltas: Vec<f64> = readings
        .iter()
        .map(|r| (r.delta_deg * 1e3).round() / 1e3)
        .collect();
    deltas.sort_by(f64::total_cmp);
    deltas.dedup();
    for (i, d) in deltas.iter().enumerate() {
        let colour = Palette99::pick(i + 1).to_rgba();
        chart
            .draw_series(
                readings
                    .iter()
                    .filter(|r| {
                        ((r.delta_deg * 1e3).round() / 1e3 - d).abs() < 1e-9 && positive(r.rho)
                    })
                    .map(|r| Circle::new((r.angle_deg, r.rho), 4, colour.filled())),
            )
            .map_err(|x| e(&x))?
            .label(format!("single-scattering reading, Δ = {d:.2}°"))
            .legend(move |(x, y)| Circle::new((x + 10, y), 4, colour.filled()));
    }
    legend(&mut chart, 14)?;
    root.present().map_err(|x| e(&x))?;
    crate::io::commit_staged(&staged, path)?;
    Ok(())
}

/// Named line series on one chart (`log_y` for loss curves).
pub fn lines(
    path: &Path,
    title: &str,
    x_desc: &str,
    y_desc: &str,
    series: &[(String, Vec<(f64, f64)>)],
    log_y: bool,
) -> crate::Result<()> {
    register_font();
    let e = |e: &dyn std::fmt::Display| e.to_string();
    let pts = series.iter().flat_map(|s| s.1.iter());
    let (mut x0, mut x1, mut y0, mut y1) = (
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
    );
    for &(x, y) in pts.filter(|(x, y)| x.is_finite() && y.is_finite() && (!log_y || *y > 0.0)) {
        (x0, x1, y0, y1) = (x0.min(x), x1.max(x), y0.min(y), y1.max(y));
    }
    if !(x0.is_finite() && y0.is_finite()) {
        return Err(format!("{title}: nothing to plot").into());
    }
    let staged = crate::io::staging_name(path);
    let root = BitMapBackend::new(&staged, (900, 600)).into_drawing_area();
    root.fill(&WHITE).map_err(|x| e(&x))?;
    let mut builder = ChartBuilder::on(&root);
    builder
        .caption(title, ("sans-serif", 22))
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(70);
    let xr = x0..x1.max(x0 + 1e-12);
    macro_rules! draw {
        ($chart:expr) => {{
            let mut chart = $chart.map_err(|x| e(&x))?;
            chart
                .configure_mesh()
                .x_desc(x_desc)
                .y_desc(y_desc)
                .label_style(("sans-serif", 15))
                .draw()
                .map_err(|x| e(&x))?;
            for (i, (name, s)) in series.iter().enumerate() {
                let colour = Palette99::pick(i).to_rgba();
                chart
                    .draw_series(LineSeries::new(s.iter().copied(), colour.stroke_width(2)))
                    .map_err(|x| e(&x))?
                    .label(name.as_str())
                    .legend(move |(x, y)| {
                        PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(2))
                    });
            }
            legend(&mut chart, 14)?;
        }};
    }
    if log_y {
        draw!(builder.build_cartesian_2d(xr, (y0 / 1.5..y1 * 1.5).log_scale()));
    } else {
        let pad = 0.05 * (y1 - y0).max(1e-12);
        draw!(builder.build_cartesian_2d(xr, (y0 - pad)..(y1 + pad)));
    }
    root.present().map_err(|x| e(&x))?;
    crate::io::commit_staged(&staged, path)?;
    Ok(())
}

/// Phase functions on a polar plot: angle `θ` from the forward direction (right) mirrored into the
/// lower half, radius `log₁₀ ρ` over the decades the series span (at most 8), with decade circles.
pub fn polar_phase(
    path: &Path,
    title: &str,
    theta_deg: &[f64],
    series: &[(String, Vec<f64>)],
) -> crate::Result<()> {
    register_font();
    let e = |e: &dyn std::fmt::Display| e.to_string();
    let top = series
        .iter()
        .flat_map(|s| s.1.iter())
        .filter(|v| v.is_finite() && **v > 0.0)
        .fold(f64::NEG_INFINITY, |a, &b| a.max(b));
    let bottom = series
        .iter()
        .flat_map(|s| s.1.iter())
        .filter(|v| v.is_finite() && **v > 0.0)
        .fold(f64::INFINITY, |a, &b| a.min(b));
    if !(top.is_finite() && bottom.is_finite()) {
        return Err(format!("{title}: nothing to plot").into());
    }
    let hi = top.log10().ceil();
    let lo = bottom.log10().floor().max(hi - 8.0);
    let radius = |v: f64| (v.max(10f64.powf(lo)).log10() - lo) / (hi - lo).max(1.0);
    let staged = crate::io::staging_name(path);
    let root = BitMapBackend::new(&staged, (900, 900)).into_drawing_area();
    root.fill(&WHITE).map_err(|x| e(&x))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 20))
        .margin(20)
        .build_cartesian_2d(-1.1..1.1, -1.1..1.1)
        .map_err(|x| e(&x))?;
    let grey = RGBColor(200, 200, 200);
    for d in 0..=((hi - lo) as i32) {
        let r = d as f64 / (hi - lo).max(1.0);
        chart
            .draw_series(LineSeries::new(
                (0..=360).map(|a| {
                    let t = (a as f64).to_radians();
                    (r * t.cos(), r * t.sin())
                }),
                grey.stroke_width(1),
            ))
            .map_err(|x| e(&x))?;
        chart
            .draw_series(std::iter::once(Text::new(
                format!("1e{}", lo as i32 + d),
                (0.0, r),
                ("sans-serif", 13).into_font().color(&BLACK.mix(0.6)),
            )))
            .map_err(|x| e(&x))?;
    }
    chart
        .draw_series(LineSeries::new(
            [(-1.05, 0.0), (1.05, 0.0)],
            grey.stroke_width(1),
        ))
        .map_err(|x| e(&x))?;
    // the first series bold and on top, the others thin beneath it
    for (i, (name, v)) in series.iter().enumerate().rev() {
        let colour = Palette99::pick(i).to_rgba();
        let width = if i == 0 { 2 } else { 1 };
        let upper = theta_deg.iter().zip(v).map(|(t, &v)| {
            let (r, t) = (radius(v), t.to_radians());
            (r * t.cos(), r * t.sin())
        });
        let lower = theta_deg.iter().zip(v).rev().map(|(t, &v)| {
            let (r, t) = (radius(v), t.to_radians());
            (r * t.cos(), -r * t.sin())
        });
        chart
            .draw_series(LineSeries::new(
                upper.chain(lower),
                colour.stroke_width(width),
            ))
            .map_err(|x| e(&x))?
            .label(name.as_str())
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(2))
            });
    }
    chart
        .configure_series_labels()
        .position(SeriesLabelPosition::UpperLeft)
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .label_font(("sans-serif", 14))
        .draw()
        .map_err(|x| e(&x))?;
    root.present().map_err(|x| e(&x))?;
    crate::io::commit_staged(&staged, path)?;
    Ok(())
}

/// A named set of measured points `(x, y, sd)`.
pub type PointSet = (String, Vec<(f64, f64, f64)>);

/// Measured points with ±1 sd error bars (one colour per named set) and model lines, on a log
/// `y` axis (non-positive values are left out).
pub fn points_and_lines(
    path: &Path,
    title: &str,
    x_desc: &str,
    y_desc: &str,
    points: &[PointSet],
    curves: &[(String, Vec<(f64, f64)>)],
) -> crate::Result<()> {
    register_font();
    let e = |e: &dyn std::fmt::Display| e.to_string();
    let xy = points
        .iter()
        .flat_map(|s| s.1.iter().map(|p| (p.0, p.1)))
        .chain(curves.iter().flat_map(|s| s.1.iter().copied()))
        .filter(|(x, y)| x.is_finite() && y.is_finite() && *y > 0.0);
    let (mut x0, mut x1, mut y0, mut y1) = (
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
    );
    for (x, y) in xy {
        (x0, x1, y0, y1) = (x0.min(x), x1.max(x), y0.min(y), y1.max(y));
    }
    if !(x0.is_finite() && y0.is_finite()) {
        return Err(format!("{title}: nothing to plot").into());
    }
    let staged = crate::io::staging_name(path);
    let root = BitMapBackend::new(&staged, (900, 600)).into_drawing_area();
    root.fill(&WHITE).map_err(|x| e(&x))?;
    let mut chart = ChartBuilder::on(&root)
        .caption(title, ("sans-serif", 22))
        .margin(15)
        .x_label_area_size(45)
        .y_label_area_size(70)
        .build_cartesian_2d(x0..x1.max(x0 + 1e-12), (y0 / 1.5..y1 * 1.5).log_scale())
        .map_err(|x| e(&x))?;
    chart
        .configure_mesh()
        .x_desc(x_desc)
        .y_desc(y_desc)
        .label_style(("sans-serif", 15))
        .draw()
        .map_err(|x| e(&x))?;
    let floor = y0 / 1.5;
    for (i, (name, p)) in points.iter().enumerate() {
        let colour = Palette99::pick(i).to_rgba();
        chart
            .draw_series(p.iter().filter(|q| q.1 > 0.0).map(|&(x, y, s)| {
                ErrorBar::new_vertical(x, (y - s).max(floor), y, y + s, colour.filled(), 6)
            }))
            .map_err(|x| e(&x))?
            .label(name.as_str())
            .legend(move |(x, y)| Circle::new((x + 10, y), 4, colour.filled()));
    }
    for (i, (name, c)) in curves.iter().enumerate() {
        let colour = Palette99::pick(points.len() + i).to_rgba();
        chart
            .draw_series(LineSeries::new(
                c.iter().copied().filter(|q| q.1 > 0.0),
                colour.stroke_width(2),
            ))
            .map_err(|x| e(&x))?
            .label(name.as_str())
            .legend(move |(x, y)| {
                PathElement::new(vec![(x, y), (x + 20, y)], colour.stroke_width(2))
            });
    }
    legend(&mut chart, 14)?;
    root.present().map_err(|x| e(&x))?;
    crate::io::commit_staged(&staged, path)?;
    Ok(())
}
