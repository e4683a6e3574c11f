//! `lightpath compare A B`: agreement of two `covariance.json` (e.g. Monte Carlo vs the wave
//! solver), light pair by light pair: the normalised error `‖A − B‖/‖B‖`, the share of entries
//! within 3 combined standard errors, and the worst entries; optional diagonal and matrix plots.

use crate::error::{Error, Result};
use crate::io::ResultFile;
use crate::io::results::{CovarianceFile, CovarianceMatrix};
use std::path::Path;

/// The report, and whether every light pair is within `tolerance`.
pub fn compare(a: &Path, b: &Path, tolerance: f64, plot: Option<&Path>) -> Result<(String, bool)> {
    let ma = CovarianceFile::read(a)?.matrix(a)?;
    let mb = CovarianceFile::read(b)?.matrix(b)?;
    if (ma.lights, ma.views) != (mb.lights, mb.views) {
        return Err(Error::input(format!(
            "shapes differ: {} has {} lights × {} views, {} has {} × {}",
            a.display(),
            ma.lights,
            ma.views,
            b.display(),
            mb.lights,
            mb.views
        )));
    }
    let (nl, nv) = (ma.lights, ma.views);
    let j = nl * nv;
    let at = |l1: usize, l2: usize, v1: usize, v2: usize| (l1 * nv + v1) * j + l2 * nv + v2;
    let mut report = String::from("lights   ‖A−B‖/‖B‖   within 3σ   worst entries [v1, v2] (z)\n");
    let mut ok = true;
    for l1 in 0..nl {
        for l2 in 0..nl {
            let (mut num, mut den, mut inside, mut worst) = (0.0, 0.0, 0usize, Vec::new());
            for v1 in 0..nv {
                for v2 in 0..nv {
                    let i = at(l1, l2, v1, v2);
                    let s = ma.stderr[i].hypot(mb.stderr[i]);
                    let d = (ma.value[i] - mb.value[i]).norm();
                    num += d * d;
                    den += mb.value[i].norm_sqr();
                    let z = if s > 0.0 {
                        d / s
                    } else if d == 0.0 {
                        0.0
                    } else {
                        f64::INFINITY
                    };
                    if z <= 3.0 {
                        inside += 1;
                    }
                    worst.push((z, v1, v2));
                }
            }
            worst.sort_by(|x, y| y.0.total_cmp(&x.0));
            let err = (num / den).sqrt();
            ok &= err <= tolerance;
            let w: Vec<String> = worst
                .iter()
                .take(3)
                .map(|(z, v1, v2)| format!("[{v1}, {v2}] ({z:.1})"))
                .collect();
            report += &format!(
                "{l1},{l2}      {err:>9.4}   {:>8.1} %   {}\n",
                100.0 * inside as f64 / (nv * nv) as f64,
                w.join(" ")
            );
        }
    }
    report += &format!(
        "{} (tolerance on ‖A−B‖/‖B‖: {tolerance})",
        if ok { "agree" } else { "DISAGREE" }
    );
    if let Some(dir) = plot {
        super::create_out(dir, &["compare_diagonals.png", "compare_matrices.png"])?;
        for f in plots(dir, (a, &ma), (b, &mb))? {
            report += &format!("\nwrote {}", f.display());
        }
    }
    Ok((report, ok))
}

/// Diagonal and matrix plots of every light pair.
fn plots(
    dir: &Path,
    (a, ma): (&Path, &CovarianceMatrix),
    (b, mb): (&Path, &CovarianceMatrix),
) -> Result<Vec<std::path::PathBuf>> {
    let (nl, nv) = (ma.lights, ma.views);
    let j = nl * nv;
    let mut pairs = Vec::new();
    for l1 in 0..nl {
        for l2 in 0..nl {
            let at = |i: usize| (l1 * nv + i / nv) * j + l2 * nv + i % nv;
            let diag = |m: &CovarianceMatrix| -> Vec<(f64, f64)> {
                (0..nv)
                    .map(|d| (m.value[at(d * nv + d)].re, m.stderr[at(d * nv + d)]))
                    .collect()
            };
            pairs.push(crate::io::plot::PairBlock {
                label: format!("{l1},{l2}"),
                a: (0..nv * nv).map(|i| ma.value[at(i)].norm()).collect(),
                b: (0..nv * nv).map(|i| mb.value[at(i)].norm()).collect(),
                diag_a: diag(ma),
                diag_b: diag(mb),
            });
        }
    }
    let name = |p: &Path| {
        p.parent()
            .and_then(|d| d.file_name())
            .and_then(|s| s.to_str())
            .unwrap_or("?")
            .to_string()
    };
    crate::io::plot::compare(dir, (&name(a), &name(b)), &pairs, nv)
}
