//! `lightpath mie`: efficiencies, cross-sections, `g`, amplitudes and the phase function of
//! spheres (Lorenz–Mie theory, optionally a log-normal size distribution) → `mie.json` + a polar
//! plot of `ρ(θ)`.

use super::{Outcome, create_out};
use crate::error::{Error, Result};
use crate::io::ResultFile;
use crate::io::results::{MieBulk, MieFile};
use crate::math::C64;
use crate::medium::mie::{Particles, Polarisation};

/// What `lightpath mie` computes.
#[derive(Clone, Debug)]
pub struct MieRequest {
    pub diameter: f64,
    pub diameter_spread: f64,
    pub n_particle: f64,
    pub k_particle: f64,
    pub n_medium: f64,
    pub vacuum_wavelength: f64,
    pub angles: usize,
    pub volume_fraction: Option<f64>,
}

fn positive(key: &str, v: f64) -> Result<()> {
    if v.is_finite() && v > 0.0 {
        Ok(())
    } else {
        Err(Error::input(format!(
            "--{key} {v}: must be a positive finite number"
        )))
    }
}

/// Check the request, compute, write `mie.json` and `mie.png` into `out`.
pub fn run(r: &MieRequest, out: &std::path::Path) -> Result<Outcome> {
    let file = compute(r)?;
    create_out(out, &["mie.json", "mie.png"])?;
    write(&file, out)
}

/// Check the request and compute `mie.json` in memory (the library's and Python's entry).
pub fn compute(r: &MieRequest) -> Result<MieFile> {
    positive("diameter", r.diameter)?;
    positive("n-particle", r.n_particle)?;
    positive("n-medium", r.n_medium)?;
    positive("wavelength", r.vacuum_wavelength)?;
    if !(r.k_particle.is_finite() && r.k_particle >= 0.0) {
        return Err(Error::input(format!(
            "--k-particle {}: must be a finite number >= 0 (absorption)",
            r.k_particle
        )));
    }
    if !(2..=100_001).contains(&r.angles) {
        return Err(Error::input(format!(
            "--angles {}: must be within [2, 100001]",
            r.angles
        )));
    }
    if let Some(f) = r.volume_fraction
        && !(f.is_finite() && f > 0.0 && f <= 0.74)
    {
        return Err(Error::input(format!(
            "--volume-fraction {f}: must be within (0, 0.74] (0.74: close-packed spheres)"
        )));
    }
    let particles = Particles {
        diameter: r.diameter,
        spread: r.diameter_spread,
        n_particle: C64::new(r.n_particle, r.k_particle),
        n_medium: r.n_medium,
        wavelength: r.vacuum_wavelength / r.n_medium,
    };
    particles
        .validate()
        .map_err(|e| Error::input(format!("--diameter-spread / --diameter: {e}")))?;
    let start = std::time::Instant::now();
    // θ from 0° to 180°: the optics want increasing cosines, so compute reversed
    let theta: Vec<f64> = (0..r.angles)
        .map(|i| 180.0 * i as f64 / (r.angles - 1) as f64)
        .collect();
    let cos: Vec<f64> = theta.iter().rev().map(|t| t.to_radians().cos()).collect();
    let o = particles
        .optics(&cos)
        .map_err(|e| Error::input(e.to_string()))?;
    // ρ normalised by the series' C_sca (exact), so each polarisation's share comes from it too
    let rev = |v: Vec<f64>| v.into_iter().rev().collect::<Vec<f64>>();
    let k = 2.0 * std::f64::consts::PI / particles.wavelength;
    let unpolarised = rev(o.phase(Polarisation::Unpolarised));
    let per_pol = |i: &[f64]| rev(i.iter().map(|v| v / o.c_sca).collect());
    let m = particles.relative_index();
    let bulk = r.volume_fraction.map(|f| {
        let density = f / o.mean_volume;
        let (s, a) = (density * o.c_sca, density * o.c_abs);
        MieBulk {
            volume_fraction: f,
            number_density: density,
            sigma_s: s,
            sigma_a: a,
            mfp: 1.0 / (s + a),
            albedo: s / (s + a),
        }
    });
    let file = MieFile {
        format_version: crate::io::results::FORMAT_VERSION,
        diameter: r.diameter,
        diameter_spread: r.diameter_spread,
        n_particle: [r.n_particle, r.k_particle],
        n_medium: r.n_medium,
        vacuum_wavelength: r.vacuum_wavelength,
        size_parameter: o.size_parameter,
        relative_index: [m.re, m.im],
        terms: o.terms,
        q_ext: o.efficiencies.ext,
        q_sca: o.efficiencies.sca,
        q_abs: o.efficiencies.abs,
        q_back: o.efficiencies.back,
        g: o.g,
        c_ext: o.c_ext,
        c_sca: o.c_sca,
        c_abs: o.c_abs,
        c_back: o.c_back,
        mean_volume: o.mean_volume,
        bulk,
        theta_deg: theta.clone(),
        phase: unpolarised.clone(),
        // dC/dΩ = ⟨|S|²⟩ / k²: each polarisation's ρ over the unpolarised C_sca
        phase_perpendicular: per_pol(&o.i1),
        phase_parallel: per_pol(&o.i2),
        s1_re: o.s1.iter().rev().map(|s| s.re * k).collect(),
        s1_im: o.s1.iter().rev().map(|s| s.im * k).collect(),
        s2_re: o.s2.iter().rev().map(|s| s.re * k).collect(),
        s2_im: o.s2.iter().rev().map(|s| s.im * k).collect(),
        seconds: start.elapsed().as_secs_f64(),
        version: env!("CARGO_PKG_VERSION").to_string(),
    };
    Ok(file)
}

/// Write `mie.json` and its polar plot `mie.png` into `out` (which exists).
pub fn write(file: &MieFile, out: &std::path::Path) -> Result<Outcome> {
    let json = out.join(MieFile::NAME);
    let png = out.join("mie.png");
    file.write(&json)?;
    let [m_re, m_im] = file.relative_index;
    crate::io::plot::polar_phase(
        &png,
        &format!(
            "Mie phase function: d = {}, m = {:.4}{:+.4}i, x = {:.2}, g = {:.4}",
            file.diameter, m_re, m_im, file.size_parameter, file.g
        ),
        &file.theta_deg,
        &[
            ("unpolarised".to_string(), file.phase.clone()),
            (
                "perpendicular (|S1|²)".to_string(),
                file.phase_perpendicular.clone(),
            ),
            ("parallel (|S2|²)".to_string(), file.phase_parallel.clone()),
        ],
    )?;
    let mut summary = format!(
        "size parameter {:.4}, {} terms: Q_ext {:.6}, Q_sca {:.6}, Q_abs {:.6}, Q_back {:.6}, g {:.6}\n\
         C_sca {:.6e}, C_abs {:.6e} (per particle)",
        file.size_parameter,
        file.terms,
        file.q_ext,
        file.q_sca,
        file.q_abs,
        file.q_back,
        file.g,
        file.c_sca,
        file.c_abs
    );
    if let Some(b) = &file.bulk {
        summary += &format!(
            "\nvolume fraction {}: sigma_s {:.6e}, sigma_a {:.6e}, mfp {:.6e}, albedo {:.6}",
            b.volume_fraction, b.sigma_s, b.sigma_a, b.mfp, b.albedo
        );
    }
    Ok(Outcome {
        files: vec![json, png],
        summary,
        not_converged: None,
    })
}
