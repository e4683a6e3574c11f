//! Convex polyhedra: clipping by half-spaces and the exact integral of `exp(b·x)` (complex `b`)
//! by the divergence theorem (volume → faces → edges). Used for closed-form speckle means.

use crate::math::{C64, CVec3};
use glam::DVec3;

/// A planar face: outward unit normal and its vertices in cyclic order.
#[derive(Clone, Debug)]
struct Face {
    normal: DVec3,
    verts: Vec<DVec3>,
}

/// A convex polyhedron given by its faces.
#[derive(Clone, Debug)]
pub struct Polyhedron {
    faces: Vec<Face>,
}

/// Below this `|b|·diameter` the integrand is expanded about the centroid (error `O((|b| d)²)`).
const SMALL: f64 = 1e-4;

impl Polyhedron {
    /// The axis-aligned box `[lo, hi]`.
    pub fn cuboid(lo: DVec3, hi: DVec3) -> Self {
        let c = |x: bool, y: bool, z: bool| {
            DVec3::new(
                if x { hi.x } else { lo.x },
                if y { hi.y } else { lo.y },
                if z { hi.z } else { lo.z },
            )
        };
        let face = |normal: DVec3, v: [DVec3; 4]| Face {
            normal,
            verts: v.to_vec(),
        };
        Polyhedron {
            faces: vec![
                face(
                    -DVec3::X,
                    [
                        c(false, false, false),
                        c(false, true, false),
                        c(false, true, true),
                        c(false, false, true),
                    ],
                ),
                face(
                    DVec3::X,
                    [
                        c(true, false, false),
                        c(true, false, true),
                        c(true, true, true),
                        c(true, true, false),
                    ],
                ),
                face(
                    -DVec3::Y,
                    [
                        c(false, false, false),
                        c(false, false, true),
                        c(true, false, true),
                        c(true, false, false),
                    ],
                ),
                face(
                    DVec3::Y,
                    [
                        c(false, true, false),
                        c(true, true, false),
                        c(true, true, true),
                        c(false, true, true),
                    ],
                ),
                face(
                    -DVec3::Z,
                    [
                        c(false, false, false),
                        c(true, false, false),
                        c(true, true, false),
                        c(false, true, false),
                    ],
                ),
                face(
                    DVec3::Z,
                    [
                        c(false, false, true),
                        c(false, true, true),
                        c(true, true, true),
                        c(true, false, true),
                    ],
                ),
            ],
        }
    }

    /// Keep the part with `n·x ≤ c` (`None` if nothing of positive volume remains).
    pub fn clip(&self, n: DVec3, c: f64) -> Option<Polyhedron> {
        let scale = self
            .faces
            .iter()
            .flat_map(|f| f.verts.iter())
            .fold(0.0f64, |m, v| m.max(v.abs().max_element()));
        let eps = 1e-12 * scale.max(1.0);
        let mut faces = Vec::new();
        let mut cap: Vec<DVec3> = Vec::new();
        for f in &self.faces {
            let mut out = Vec::new();
            let k = f.verts.len();
            for i in 0..k {
                let (p, q) = (f.verts[i], f.verts[(i + 1) % k]);
                let (dp, dq) = (n.dot(p) - c, n.dot(q) - c);
                if dp <= eps {
                    out.push(p);
                    if dp.abs() <= eps {
                        cap.push(p);
                    }
                }
                if (dp < -eps && dq > eps) || (dp > eps && dq < -eps) {
                    let x = p + (q - p) * (dp / (dp - dq));
                    out.push(x);
                    cap.push(x);
                }
            }
            if out.len() >= 3 {
                faces.push(Face {
                    normal: f.normal,
                    verts: out,
                });
            }
        }
        if faces.is_empty() {
            return None;
        }
        // the cap polygon on the cutting plane
        let mut uniq: Vec<DVec3> = Vec::new();
        for p in cap {
            if !uniq.iter().any(|q| (*q - p).length() <= 10.0 * eps) {
                uniq.push(p);
            }
        }
        if uniq.len() >= 3 {
            let centre = uniq.iter().copied().sum::<DVec3>() / uniq.len() as f64;
            let (e1, e2) = crate::math::orthonormal_basis(n.normalize());
            uniq.sort_by(|a, b| {
                let (da, db) = (*a - centre, *b - centre);
                da.dot(e2)
                    .atan2(da.dot(e1))
                    .total_cmp(&db.dot(e2).atan2(db.dot(e1)))
            });
            faces.push(Face {
                normal: n.normalize(),
                verts: uniq,
            });
        }
        let p = Polyhedron { faces };
        (p.volume_centroid().0 > eps * eps * eps).then_some(p)
    }

    /// Volume and centroid (tetrahedra from the vertex mean, which is interior).
    pub fn volume_centroid(&self) -> (f64, DVec3) {
        let all: Vec<DVec3> = self
            .faces
            .iter()
            .flat_map(|f| f.verts.iter().copied())
            .collect();
        let p0 = all.iter().copied().sum::<DVec3>() / all.len().max(1) as f64;
        let (mut vol, mut mom) = (0.0, DVec3::ZERO);
        for f in &self.faces {
            for i in 1..f.verts.len().saturating_sub(1) {
                let (a, b, c) = (f.verts[0], f.verts[i], f.verts[i + 1]);
                let v = ((a - p0).dot((b - p0).cross(c - p0)) / 6.0).abs();
                vol += v;
                mom += (p0 + a + b + c) * (v / 4.0);
            }
        }
        (vol, if vol > 0.0 { mom / vol } else { p0 })
    }

    fn diameter(&self) -> f64 {
        let all: Vec<DVec3> = self
            .faces
            .iter()
            .flat_map(|f| f.verts.iter().copied())
            .collect();
        let mut d: f64 = 0.0;
        for (i, a) in all.iter().enumerate() {
            for b in &all[i + 1..] {
                d = d.max((*a - *b).length());
            }
        }
        d
    }

    /// `∫_P exp(c + b·x) dx`, exactly: `(1/|b|²) Σ_F (b̄·n_F) ∫_F exp(c + b·x) dA`. The constant `c`
    /// is added inside every exponential, so large but cancelling exponents cannot overflow.
    pub fn integrate_exp(&self, b: CVec3, c: C64) -> C64 {
        let nb = b.norm_sqr();
        if nb.sqrt() * self.diameter() < SMALL {
            let (v, x) = self.volume_centroid();
            return (c + b.dot_real(x)).exp() * v;
        }
        let mut acc = C64::default();
        for f in &self.faces {
            acc += b.conj_dot(f.normal) * face_integral(f, b, c);
        }
        acc / nb
    }
}

/// Area and centroid of a planar polygon (fan triangulation).
fn area_centroid(f: &Face) -> (f64, DVec3) {
    let (mut area, mut mom) = (0.0, DVec3::ZERO);
    for i in 1..f.verts.len() - 1 {
        let (a, b, c) = (f.verts[0], f.verts[i], f.verts[i + 1]);
        let t = 0.5 * (b - a).cross(c - a).length();
        area += t;
        mom += (a + b + c) * (t / 3.0);
    }
    (area, if area > 0.0 { mom / area } else { f.verts[0] })
}

/// `(e^δ − 1)/δ`, accurate for small `δ`.
fn phi(d: C64) -> C64 {
    if d.norm() < 1e-3 {
        C64::new(1.0, 0.0) + d / 2.0 + d * d / 6.0 + d * d * d / 24.0
    } else {
        (d.exp() - 1.0) / d
    }
}

/// `∫_F exp(c + b·x) dA` over a planar face by the divergence theorem in its plane.
fn face_integral(f: &Face, b: CVec3, c: C64) -> C64 {
    let bt = b.tangential(f.normal);
    let (area, centre) = area_centroid(f);
    let k = f.verts.len();
    let span = f
        .verts
        .iter()
        .fold(0.0f64, |m, v| m.max((*v - centre).length()))
        * 2.0;
    let nbt = bt.norm_sqr();
    if nbt.sqrt() * span < SMALL {
        return (c + b.dot_real(centre)).exp() * area;
    }
    let mut acc = C64::default();
    for i in 0..k {
        let (p, q) = (f.verts[i], f.verts[(i + 1) % k]);
        let e = q - p;
        let len = e.length();
        if len == 0.0 {
            continue;
        }
        let mut m = f.normal.cross(e) / len;
        if m.dot((p + q) * 0.5 - centre) < 0.0 {
            m = -m;
        }
        let (a0, a1) = (c + b.dot_real(p), c + b.dot_real(q));
        acc += bt.conj_dot(m) * a0.exp() * phi(a1 - a0) * len;
    }
    acc / nbt
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn box_integral_is_product_of_1d_integrals() {
        let (lo, hi) = (DVec3::new(-1.0, -0.5, 0.0), DVec3::new(2.0, 1.5, 0.7));
        let b = CVec3 {
            re: DVec3::new(-0.3, 0.2, 0.0),
            im: DVec3::new(4.0, -1.0, 0.5),
        };
        let one = |br: f64, bi: f64, l: f64, h: f64| {
            let z = C64::new(br, bi);
            if z.norm() == 0.0 {
                C64::new(h - l, 0.0)
            } else {
                ((z * h).exp() - (z * l).exp()) / z
            }
        };
        let expect = one(b.re.x, b.im.x, lo.x, hi.x)
            * one(b.re.y, b.im.y, lo.y, hi.y)
            * one(b.re.z, b.im.z, lo.z, hi.z);
        let got = Polyhedron::cuboid(lo, hi).integrate_exp(b, C64::default());
        assert!(
            (got - expect).norm() < 1e-12 * expect.norm(),
            "{got} vs {expect}"
        );
        let v = Polyhedron::cuboid(lo, hi).integrate_exp(CVec3::default(), C64::default());
        assert!((v.re - 3.0 * 2.0 * 0.7).abs() < 1e-12);
    }

    #[test]
    fn clipped_cube_is_a_prism() {
        // cube [0,1]³ cut by x + y ≤ 1: a triangular prism of volume 1/2; ∫ e^{b z} = ½ (e^b − 1)/b
        let p = Polyhedron::cuboid(DVec3::ZERO, DVec3::ONE)
            .clip(DVec3::new(1.0, 1.0, 0.0), 1.0)
            .unwrap();
        assert!((p.volume_centroid().0 - 0.5).abs() < 1e-12);
        let b = CVec3 {
            re: DVec3::new(0.0, 0.0, 0.7),
            im: DVec3::new(0.0, 0.0, 2.0),
        };
        let z = C64::new(0.7, 2.0);
        let expect = (z.exp() - 1.0) / z * 0.5;
        assert!((p.integrate_exp(b, C64::default()) - expect).norm() < 1e-12);
        // a general b against midpoint quadrature on a fine grid
        let b = CVec3 {
            re: DVec3::new(0.3, -0.2, 0.1),
            im: DVec3::new(1.0, 2.0, -3.0),
        };
        let n = 120;
        let mut q = C64::default();
        for i in 0..n {
            for j in 0..n {
                for k in 0..n {
                    let x = DVec3::new(i as f64 + 0.5, j as f64 + 0.5, k as f64 + 0.5) / n as f64;
                    // cells centred on the cut count half
                    let w = match (i + j + 1).cmp(&n) {
                        std::cmp::Ordering::Less => 1.0,
                        std::cmp::Ordering::Equal => 0.5,
                        std::cmp::Ordering::Greater => 0.0,
                    };
                    q += b.dot_real(x).exp() * w;
                }
            }
        }
        q /= (n * n * n) as f64;
        let got = p.integrate_exp(b, C64::new(0.3, -1.0)) * C64::new(-0.3, 1.0).exp();
        assert!((got - q).norm() < 1e-4 * q.norm(), "{got} vs {q}");
        assert!(
            Polyhedron::cuboid(DVec3::ZERO, DVec3::ONE)
                .clip(DVec3::X, -0.5)
                .is_none()
        );
    }
}
