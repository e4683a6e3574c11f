//! Lights and views as path endpoints: the complex transmission `ξ` and attenuation `τ` of a
//! connection from a vertex inside the medium (paper 001, Eqs. 13 and 19).

use crate::math::{C64, cis};
use crate::medium::Medium;
use glam::DVec3;

/// A light (source) of unit amplitude.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Light {
    /// Plane wave `exp(i k d·x)` propagating along unit `direction`.
    PlaneWave { direction: DVec3 },
    /// Isotropic point source `exp(i k r) / r` at `position`.
    Point { position: DVec3 },
    /// Focused beam: plane waves apodised by the von Mises–Fisher mask `exp(γ (w·axis − 1))`,
    /// `u(x) = ∫ m(w) exp(i k w·(x − focus)) dw = 4π e^{-γ} sinh(q)/q`, `q² = μ·μ`,
    /// `μ = γ axis + i k (x − focus)` (paper 000, Eq. 29). Wave solver only.
    Focused {
        focus: DVec3,
        axis: DVec3,
        gamma: f64,
    },
}

/// A view (sensor).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum View {
    /// Far-field sensor collecting light leaving along unit `direction`: `ξ(x → v) = exp(-i k v·x)`.
    FarField { direction: DVec3 },
    /// Point sensor at `position`: `ξ(x → v) = exp(i k r) / r`.
    Point { position: DVec3 },
    /// Focused sensor collecting far-field directions `w` with the mask `exp(γ (w·axis − 1))`,
    /// refocused at `focus`: `ξ(x → v) = 4π e^{-γ} sinh(q)/q`, `μ = γ axis − i k (x − focus)`.
    /// Wave solver only.
    Focused {
        focus: DVec3,
        axis: DVec3,
        gamma: f64,
    },
}

/// The error for endpoints the Monte Carlo estimators do not support.
pub const FOCUSED_UNSUPPORTED: &str = "focused lights and views are supported by `lightpath wave` only; the Monte Carlo estimators take plane_wave, point and far_field endpoints";

/// An endpoint seen from a vertex: either "far" (a direction) or "near" (a point). By reciprocity a
/// plane-wave light propagating along `d` is the far endpoint with outgoing direction `-d`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Endpoint {
    /// Far endpoint reached by leaving along unit `dir`.
    Far { dir: DVec3 },
    /// Near endpoint at `pos`.
    Near { pos: DVec3 },
}

impl TryFrom<Light> for Endpoint {
    type Error = &'static str;
    fn try_from(l: Light) -> Result<Self, Self::Error> {
        match l {
            Light::PlaneWave { direction } => Ok(Endpoint::Far { dir: -direction }),
            Light::Point { position } => Ok(Endpoint::Near { pos: position }),
            Light::Focused { .. } => Err(FOCUSED_UNSUPPORTED),
        }
    }
}

impl TryFrom<View> for Endpoint {
    type Error = &'static str;
    fn try_from(v: View) -> Result<Self, Self::Error> {
        match v {
            View::FarField { direction } => Ok(Endpoint::Far { dir: direction }),
            View::Point { position } => Ok(Endpoint::Near { pos: position }),
            View::Focused { .. } => Err(FOCUSED_UNSUPPORTED),
        }
    }
}

/// A connection from a vertex to an endpoint: `prop = τ ξ` and the unit direction `dir` in which the
/// light leaves the vertex towards the endpoint.
#[derive(Clone, Copy, Debug, Default)]
pub struct Connection {
    pub prop: C64,
    pub dir: DVec3,
    /// Length of the connection inside the medium (`τ = exp(-σ_t inside / 2)`).
    pub inside: f64,
}

impl Endpoint {
    /// `τ(x, e) ξ(x → e)` and the leaving direction, for a vertex `x` inside the medium.
    #[inline]
    pub fn connect(&self, x: DVec3, medium: &Medium, k: f64) -> Connection {
        match *self {
            Endpoint::Far { dir } => {
                let inside = medium.geometry.exit_distance(x, dir);
                Connection {
                    prop: cis(-k * dir.dot(x)) * medium.amplitude_attenuation(inside),
                    dir,
                    inside,
                }
            }
            Endpoint::Near { pos } => {
                let d = pos - x;
                let r = d.length();
                let dir = d / r;
                let inside = medium.geometry.exit_distance(x, dir).min(r);
                let tau = medium.amplitude_attenuation(inside);
                Connection {
                    prop: cis(k * r) * (tau / r),
                    dir,
                    inside,
                }
            }
        }
    }
}
