//! `lightpath compare A B`: agreement of two `covariance.json` (e.g. Monte Carlo vs the wave
//! solver), light pair by light pair: the normalised error `‖A − B‖/‖B‖`, the share of entries
//! within 3 combined standard errors, and the worst entries; optional diagonal and matrix plots.

use crate::error::{Error, Result};
use crate::io::ResultFile;
use crate::io::results::{CovarianceFile, CovarianceMatrix};
use std::path::Path;

/// How well one light pair `(l1, l2)` of two covariances agrees.
#[derive(Clone, Debug, PartialEq)]
pub struct PairAgreement {
    pub lights: (usize, usize),
    /// `‖A − B‖ / ‖B‖` over the pair's `V × V` entries.
    pub error: f64,
    /// The share of entries within 3 combined standard errors.
    pub within_3se: f64,
    /// The three worst entries: `(z, v1, v2)`, `z = |A − B| / √(s_A² + s_B²)`.
    pub worst: Vec<(f64, usize, usize)>,
}

/// The agreement of every light pair of `a` with `b` (same lights and views).
pub fn agreement(a: &CovarianceMatrix, b: &CovarianceMatrix) -> Result<Vec<PairAgreement>> {
    if (a.lights, a.views) != (b.lights, b.views) {
        return Err(Error::input(format!(
            "shapes differ: A has {} lights × {} views, B has {} × {}",
            a.lights, a.views, b.lights, b.views
        )));
    }
    let (nl, nv) = (a.lights, a.views);
    let j = nl * nv;
    let at = |l1: usize, l2: usize, v1: usize, v2: usize| (l1 * nv + v1) * j + l2 * nv + v2;
    let mut pairs = Vec::with_capacity(nl * nl);
    for l1 in 0..nl {
        for l2 in 0..nl {
            let (mut num, mut den, mut inside, mut worst) = (0.0, 0.0, 0usize, Vec::new());
            for v1 in 0..nv {
                for v2 in 0..nv {
                    let i = at(l1, l2, v1, v2);
                    let s = a.stderr[i].hypot(b.stderr[i]);
                    let d = (a.value[i] - b.value[i]).norm();
                    num += d * d;
                    den += b.value[i].norm_sqr();
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
            worst.truncate(3);
            pairs.push(PairAgreement {
                lights: (l1, l2),
                error: (num / den).sqrt(),
                within_3se: inside as f64 / (nv * nv) as f64,
                worst,
            });
        }
    }
    Ok(pairs)
}

/// The report of [`agreement`], and whether every light pair is within `tolerance`.
pub fn report(pairs: &[PairAgreement], tolerance: f64) -> (String, bool) {
    let mut report = String::from("lights   ‖A−B‖/‖B‖   within 3σ   worst entries [v1, v2] (z)\n");
    let mut ok = true;
    for p in pairs {
        ok &= p.error <= tolerance;
        let w: Vec<String> = p
            .worst
            .iter()
            .map(|(z, v1, v2)| format!("[{v1}, {v2}] ({z:.1})"))
            .collect();
        report += &format!(
            "{},{}      {:>9.4}   {:>8.1} %   {}\n",
            p.lights.0,
            p.lights.1,
            p.error,
            100.0 * p.within_3se,
            w.join(" ")
        );
    }
    report += &format!(
        "{} (tolerance on ‖A−B‖/‖B‖: {tolerance})",
        if ok { "agree" } else { "DISAGREE" }
    );
    (report, ok)
}

/// The report, and whether every light pair is within `tolerance`.
pub fn compare(a: &Path, b: &Path, tolerance: f64, plot: Option<&Path>) -> Result<(String, bool)> {
    let ma = CovarianceFile::read(a)?.matrix(a)?;
    let mb = CovarianceFile::read(b)?.matrix(b)?;
    let pairs = agreement(&ma, &mb)
        .map_err(|e| Error::input(format!("A = {}, B = {}: {e}", a.display(), b.display())))?;
    let (mut report, ok) = report(&pairs, tolerance);
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
