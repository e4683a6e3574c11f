//! PNG plots (plotters with an embedded DejaVu font, so no system fonts are needed).

use crate::jobs::MemoryCurve;
use plotters::prelude::*;
use std::path::Path;
use std::sync::Once;

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

/// Memory-effect curve with error bars and the diffusion prediction (paper 001, Eq. 39).
pub fn memory_effect(path: &Path, c: &MemoryCurve) -> Result<(), String> {
    register_font();
    let e = |e: &dyn std::fmt::Display| e.to_string();
    let root = BitMapBackend::new(path, (800, 560)).into_drawing_area();
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
            (a, crate::jobs::diffusion_correlation(c.kl, a.to_radians()))
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
    chart
        .configure_series_labels()
        .background_style(WHITE.mix(0.8))
        .border_style(BLACK)
        .label_font(("sans-serif", 15))
        .draw()
        .map_err(|x| e(&x))?;
    root.present().map_err(|x| e(&x))?;
    Ok(())
}
