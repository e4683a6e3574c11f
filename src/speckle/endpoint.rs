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
}

/// A view (sensor).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum View {
    /// Far-field sensor collecting light leaving along unit `direction`: `ξ(x → v) = exp(-i k v·x)`.
    FarField { direction: DVec3 },
    /// Point sensor at `position`: `ξ(x → v) = exp(i k r) / r`.
    Point { position: DVec3 },
}

/// An endpoint seen from a vertex: either "far" (a direction) or "near" (a point). By reciprocity a
/// plane-wave light propagating along `d` is the far endpoint with outgoing direction `-d`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Endpoint {
    /// Far endpoint reached by leaving along unit `dir`.
    Far { dir: DVec3 },
    /// Near endpoint at `pos`.
    Near { pos: DVec3 },
}

impl From<Light> for Endpoint {
    fn from(l: Light) -> Self {
        match l {
            Light::PlaneWave { direction } => Endpoint::Far { dir: -direction },
            Light::Point { position } => Endpoint::Near { pos: position },
        }
    }
}

impl From<View> for Endpoint {
    fn from(v: View) -> Self {
        match v {
            View::FarField { direction } => Endpoint::Far { dir: direction },
            View::Point { position } => Endpoint::Near { pos: position },
        }
    }
}

/// A connection from a vertex to an endpoint: `prop = τ ξ` and the unit direction `dir` in which the
/// light leaves the vertex towards the endpoint.
#[derive(Clone, Copy, Debug, Default)]
pub struct Connection {
    pub prop: C64,
    pub dir: DVec3,
}

impl Endpoint {
    /// `τ(x, e) ξ(x → e)` and the leaving direction, for a vertex `x` inside the medium.
    #[inline]
    pub fn connect(&self, x: DVec3, medium: &Medium, k: f64) -> Connection {
        match *self {
            Endpoint::Far { dir } => {
                let tau = medium.amplitude_attenuation(medium.geometry.exit_distance(x, dir));
                Connection {
                    prop: cis(-k * dir.dot(x)) * tau,
                    dir,
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
                }
            }
        }
    }
}
