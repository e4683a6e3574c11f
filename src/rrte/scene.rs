//! What a refractive render holds: a scattering volume with an index field, a light, and sensors
//! outside the volume that record the light leaving it.

use super::connect::Aim;
use crate::eikonal::grid::{GridField, Interp};
use crate::eikonal::{BoundedField, Bounds, Part, Profile};
use crate::math::{orthonormal_basis, uniform_sphere};
use crate::medium::Scattering;
use glam::DVec3;
use std::f64::consts::PI;

/// A refractive, scattering volume: the index field `n(x)` inside its bounds (`n_out` outside, a
/// smooth dielectric interface where the two differ), and bulk scattering, homogeneous or scaled by
/// a density.
#[derive(Clone, Debug, PartialEq)]
pub struct Volume {
    pub field: BoundedField,
    /// Scattering coefficient `σ_s` (1/length) inside the bounds, at density 1.
    pub sigma_s: f64,
    /// Absorption coefficient `σ_a` (1/length) inside the bounds, at density 1.
    pub sigma_a: f64,
    pub scattering: Scattering,
    /// `None`: homogeneous; else `σ_s ρ(x)` and `σ_a ρ(x)` (the albedo stays constant).
    pub density: Option<Density>,
    /// Where the bounds are several volumes ([`Bounds::Parts`]), each one's bulk, in their
    /// order (`sigma_s`, `sigma_a` and `scattering` above are then unused); empty for one volume.
    /// A density scales every part's coefficients.
    pub parts: Vec<Bulk>,
}

/// The bulk scattering of one of several volumes: coefficients (at density 1) and phase function.
#[derive(Clone, Debug, PartialEq)]
pub struct Bulk {
    pub sigma_s: f64,
    pub sigma_a: f64,
    pub scattering: Scattering,
}

impl Bulk {
    pub fn sigma_t(&self) -> f64 {
        self.sigma_s + self.sigma_a
    }
}

/// A density `ρ(x) ≥ 0` scaling both coefficients (a heterogeneous medium), sampled on a grid:
/// flights are drawn against the majorant `σ_t · max ρ` and kept as collisions with probability
/// `ρ(x)/max ρ` (delta tracking), transmittances along connections estimated by ratio tracking.
#[derive(Clone, Debug, PartialEq)]
pub struct Density {
    pub grid: GridField,
    /// A bound on `ρ` everywhere: the largest sample (trilinear) or B-spline coefficient
    /// (tricubic: every value is a convex combination of coefficients).
    pub max: f64,
}

impl Density {
    /// The density of `grid`, refused (with the reason) where it could be negative or is zero
    /// everywhere.
    pub fn new(grid: GridField) -> Result<Self, String> {
        if let Some(c) = grid.coef.iter().find(|c| !(**c >= 0.0 && c.is_finite())) {
            return Err(match grid.interp {
                Interp::Trilinear => format!("a sample is {c}: densities must be finite and >= 0"),
                Interp::Tricubic => format!(
                    "a B-spline coefficient is {c}: the tricubic interpolant would go negative (ringing next to sharp edges); use interp = \"trilinear\""
                ),
            });
        }
        let max = grid.coef.iter().cloned().fold(0.0, f64::max);
        if max <= 0.0 {
            return Err("every sample is 0: leave the medium out instead".into());
        }
        Ok(Density { grid, max })
    }

    /// `ρ(x)` (the value alone: delta tracking asks at every tentative collision).
    #[inline]
    pub fn at(&self, x: DVec3) -> f64 {
        self.grid.value(x)
    }
}

impl Volume {
    /// Several disjoint volumes, each with its bulk, in surroundings of index `n_out`, as one
    /// volume of parts (homogeneous: no density).
    pub fn several(parts: Vec<(Part, Bulk)>, n_out: f64) -> Self {
        let (shapes, bulks): (Vec<Part>, Vec<Bulk>) = parts.into_iter().unzip();
        let shapes: std::sync::Arc<[Part]> = shapes.into();
        Volume {
            field: BoundedField::single(
                Profile::Parts(shapes.clone()),
                Bounds::Parts(shapes),
                n_out,
            ),
            sigma_s: 0.0,
            sigma_a: 0.0,
            scattering: Scattering::single(crate::medium::PhaseFunction::Isotropic),
            density: None,
            parts: bulks,
        }
    }

    /// Extinction `σ_t = σ_s + σ_a` (at density 1); of several volumes, the smallest (what
    /// bounds a path's attenuation from below, and what estimates of work take).
    pub fn sigma_t(&self) -> f64 {
        if self.parts.is_empty() {
            return self.sigma_s + self.sigma_a;
        }
        self.parts
            .iter()
            .map(Bulk::sigma_t)
            .fold(f64::INFINITY, f64::min)
    }

    /// Single-scattering albedo (1 when nothing interacts) of one volume (not of several: see
    /// [`Self::albedo_at`]).
    pub fn albedo(&self) -> f64 {
        albedo(self.sigma_s, self.sigma_a)
    }

    /// Which part holds `x` (or is nearest), where the bounds are several volumes.
    #[inline]
    pub fn part_index(&self, x: DVec3) -> Option<usize> {
        let parts = self
            .field
            .bounds
            .parts()
            .filter(|_| !self.parts.is_empty())?;
        Some(crate::eikonal::part_at(parts, x))
    }

    /// The bulk of the part holding `x` (or the nearest), where the bounds are several volumes.
    #[inline]
    fn part(&self, x: DVec3) -> Option<&Bulk> {
        self.part_index(x).map(|k| &self.parts[k])
    }

    /// `(σ_s, σ_t)` at density 1 of `part` ([`Self::part_index`]; `None`: the one volume).
    #[inline]
    pub fn coefficients(&self, part: Option<usize>) -> (f64, f64) {
        match part {
            Some(k) => (self.parts[k].sigma_s, self.parts[k].sigma_t()),
            None => (self.sigma_s, self.sigma_s + self.sigma_a),
        }
    }

    /// The phase function of `part` ([`Self::part_index`]; `None`: the one volume).
    #[inline]
    pub fn scattering_of(&self, part: Option<usize>) -> &Scattering {
        part.map_or(&self.scattering, |k| &self.parts[k].scattering)
    }

    /// How rays bend at `x` (inside): `∇n / n`, the curvature of a ray running across the
    /// gradient (zero in a constant index).
    pub fn bend(&self, x: DVec3) -> DVec3 {
        let (n, grad) = self.field.value_grad(x);
        grad / n
    }

    /// Extinction at density 1 at `x` (inside).
    #[inline]
    pub fn sigma_t_at(&self, x: DVec3) -> f64 {
        self.part(x)
            .map_or(self.sigma_s + self.sigma_a, Bulk::sigma_t)
    }

    /// Single-scattering albedo at `x` (inside).
    #[inline]
    pub fn albedo_at(&self, x: DVec3) -> f64 {
        match self.part(x) {
            Some(b) => albedo(b.sigma_s, b.sigma_a),
            None => self.albedo(),
        }
    }

    /// The phase function at `x` (inside).
    #[inline]
    pub fn scattering_at(&self, x: DVec3) -> &Scattering {
        self.part(x).map_or(&self.scattering, |b| &b.scattering)
    }

    /// The extinction free flights from `x` (inside) are drawn against: `σ_t` of the part
    /// holding `x` (a flight stays in it) times the density's bound.
    #[inline]
    pub fn majorant_at(&self, x: DVec3) -> f64 {
        self.sigma_t_at(x) * self.density.as_ref().map_or(1.0, |d| d.max)
    }

    /// Whether `n` is constant inside (every profile constant): rays are then straight lines,
    /// traced in closed form instead of stepped.
    pub fn homogeneous(&self) -> bool {
        self.field.profiles.iter().all(Profile::is_constant)
    }

    /// Whether `n` inside (constant: see [`Self::homogeneous`]) equals `n_out` in every part.
    pub fn index_matched(&self) -> bool {
        let field = &self.field;
        let n_out = field.n_out;
        match field.bounds.parts() {
            Some(parts) => parts
                .iter()
                .all(|p| field.offset + field.scale * p.index(p.center) == n_out),
            // the constant inside, read without the bounds (which need not hold the origin)
            None => field.eval_inside(DVec3::ZERO).0 == n_out,
        }
    }

    /// The largest distance from the origin to the volume's surface `h(d)` along unit `d` (the
    /// support function of the bounds): the volume lies within `x·d ≤ h(d)`.
    pub fn support(&self, d: DVec3) -> f64 {
        support(&self.field.bounds, d)
    }
}

/// The support function `h(d)` of `bounds` along unit `d`: they lie within `x·d ≤ h(d)`.
fn support(bounds: &Bounds, d: DVec3) -> f64 {
    match *bounds {
        Bounds::Everywhere => f64::INFINITY,
        Bounds::Sphere { radius } => radius,
        Bounds::Box { half } => (half * d.abs()).element_sum(),
        Bounds::Cylinder {
            radius,
            half_length,
        } => radius * (d.x * d.x + d.y * d.y).sqrt() + half_length * d.z.abs(),
        Bounds::Sdf(ref g) => {
            let (lo, hi) = g.corners();
            (lo * d).max(hi * d).element_sum()
        }
        Bounds::Parts(ref parts) => parts
            .iter()
            .map(|p| p.center.dot(d) + support(&p.shape, d))
            .fold(f64::NEG_INFINITY, f64::max),
    }
}

/// `σ_s / σ_t` (1 when nothing interacts).
fn albedo(sigma_s: f64, sigma_a: f64) -> f64 {
    if sigma_s + sigma_a > 0.0 {
        sigma_s / (sigma_s + sigma_a)
    } else {
        1.0
    }
}

/// The pixel (row-major from the lower left, the first axis fastest) at fractions `a`, `b` in
/// `[0, 1)` across an image of `pixels`.
#[inline]
pub fn grid_pixel(a: f64, b: f64, pixels: [usize; 2]) -> usize {
    let i = ((a * pixels[0] as f64) as usize).min(pixels[0] - 1);
    let j = ((b * pixels[1] as f64) as usize).min(pixels[1] - 1);
    j * pixels[0] + i
}

/// The pixels a point at fractions `(a, b)` of an image adds to, with their shares.
pub type Shares = ([(usize, f64); 4], usize);

/// Per axis, the two pixels whose centres surround the fraction `f` of `pixels` (where they
/// exist): each one's index, tent weight and the weight's slope in `f`.
#[inline]
fn tent_axis(f: f64, pixels: usize) -> [Option<(usize, f64, f64)>; 2] {
    let u = f * pixels as f64 - 0.5;
    let lower = u.floor();
    let frac = u - lower;
    let count = pixels as f64;
    [(lower, 1.0 - frac, -count), (lower + 1.0, frac, count)]
        .map(|(k, w, g)| (k >= 0.0 && k < count).then_some((k as usize, w, g)))
}

/// The pixels a point at fractions `(a, b)` of an image of `pixels` adds to, with their shares
/// and the shares' slopes in `(a, b)`: bilinearly to the (up to) four whose centres surround it.
#[inline]
fn tent(a: f64, b: f64, pixels: [usize; 2]) -> ([(usize, f64, [f64; 2]); 4], usize) {
    let mut out = ([(0, 0.0, [0.0; 2]); 4], 0);
    let xs = tent_axis(a, pixels[0]);
    for &(j, wy, gy) in tent_axis(b, pixels[1]).iter().flatten() {
        for &(i, wx, gx) in xs.iter().flatten() {
            if wx * wy > 0.0 {
                out.0[out.1] = (j * pixels[0] + i, wx * wy, [gx * wy, gy * wx]);
                out.1 += 1;
            }
        }
    }
    out
}

/// The pixels a point at fractions `(a, b)` of an image of `pixels` adds to under `filter`, with
/// their shares: the one it falls in, or bilinearly the (up to) four whose centres surround it.
pub fn shares(filter: Filter, a: f64, b: f64, pixels: [usize; 2]) -> Shares {
    let mut out = ([(0, 0.0); 4], 0);
    match filter {
        Filter::Box => {
            if (0.0..1.0).contains(&a) && (0.0..1.0).contains(&b) {
                out.0[0] = (grid_pixel(a, b, pixels), 1.0);
                out.1 = 1;
            }
        }
        Filter::Tent => {
            let (t, count) = tent(a, b, pixels);
            for (o, &(pixel, share, _)) in out.0.iter_mut().zip(&t[..count]) {
                *o = (pixel, share);
            }
            out.1 = count;
        }
    }
    out
}

/// A named window of a camera's pixels whose sum is an output of its own, with its own standard
/// error and derivatives: the light reaching a spot of the image (a relay's focus, a guided
/// spot's core), which a design can maximise.
#[derive(Clone, Debug, PartialEq)]
pub struct PixelWindow {
    pub name: String,
    /// First and last column, counted from the image's left.
    pub columns: [usize; 2],
    /// First and last row, counted from the image's bottom as the estimate holds them (the files
    /// show the top row first).
    pub rows: [usize; 2],
}

impl PixelWindow {
    /// Whether pixel `p` (row-major from the lower left) of an image `width` pixels wide lies in
    /// the window.
    #[inline]
    pub fn contains(&self, p: usize, width: usize) -> bool {
        let (i, j) = (p % width, p / width);
        (self.columns[0]..=self.columns[1]).contains(&i)
            && (self.rows[0]..=self.rows[1]).contains(&j)
    }
}

/// How far from a collimated beam's straight tube, per unit length along it, bidirectional
/// tracing tries to connect the beam to an event (a slope of one in five, about 11°). The
/// connection solves for a path out of the volume back along the beam and keeps it only if it
/// meets the beam's disc: for a thin beam nearly every try fails, each at the cost of a Newton
/// solve. Which events are tried is a fixed function of the event's position, counted alike by
/// the weights, so the estimate stays unbiased; light bent further from the tube is made by the
/// other strategies. (Path tracing, which has no other, tries every event.)
pub const BEAM_REACH: f64 = 0.2;

/// Where light comes from; power 1 in total (results are fractions of the emitted power).
#[derive(Clone, Debug, PartialEq)]
pub enum Light {
    /// A collimated laser beam of uniform intensity over a disc of `radius` about `center`,
    /// travelling along unit `direction` (radius 0: a single ray).
    Beam {
        center: DVec3,
        direction: DVec3,
        radius: f64,
    },
    /// A beam focused by a lens outside the volume: uniform over a disc of `radius` about
    /// `center` normal to unit `direction`, each ray aimed at `focus` (geometric optics).
    FocusedBeam {
        center: DVec3,
        direction: DVec3,
        radius: f64,
        focus: DVec3,
    },
    /// An isotropic point source.
    Point { position: DVec3 },
    /// A point source emitting uniformly into the cone of `half_angle` (radians) about unit `axis`.
    Spot {
        position: DVec3,
        axis: DVec3,
        half_angle: f64,
    },
    /// A Lambertian rectangle of `size` about `center`, emitting to the side of unit `normal`;
    /// `right` (unit, ⟂ normal) is its first side.
    Area {
        center: DVec3,
        normal: DVec3,
        right: DVec3,
        size: [f64; 2],
    },
}

/// A point uniform over the disc of `radius` about `center` normal to `direction`, from `u[0]`
/// and `u[1]`.
fn disc_point(center: DVec3, direction: DVec3, radius: f64, u: [f64; 4]) -> DVec3 {
    let (a, b) = orthonormal_basis(direction);
    let r = radius * u[0].sqrt();
    let phi = 2.0 * PI * u[1];
    center + (a * phi.cos() + b * phi.sin()) * r
}

impl Light {
    /// A start position and unit direction from four uniform numbers (each with its density over
    /// the light's area and directions, so every photon carries the same power).
    pub fn sample(&self, u: [f64; 4]) -> (DVec3, DVec3) {
        match *self {
            Light::Beam {
                center,
                direction,
                radius,
            } => (disc_point(center, direction, radius, u), direction),
            Light::FocusedBeam {
                center,
                direction,
                radius,
                focus,
            } => {
                let x = disc_point(center, direction, radius, u);
                (x, (focus - x).normalize())
            }
            Light::Point { position } => (position, uniform_sphere(u[0], u[1])),
            Light::Spot {
                position,
                axis,
                half_angle,
            } => {
                // uniform in solid angle over the cap: cos θ uniform in [cos α, 1]
                let mu = 1.0 - u[0] * (1.0 - half_angle.cos());
                (
                    position,
                    crate::math::direction_about(axis, mu, 2.0 * PI * u[1]),
                )
            }
            Light::Area {
                center,
                normal,
                right,
                size,
            } => {
                let up = normal.cross(right);
                let x = center + right * ((u[0] - 0.5) * size[0]) + up * ((u[1] - 0.5) * size[1]);
                // cosine-weighted hemisphere about the normal
                let mu = u[2].sqrt();
                (x, crate::math::direction_about(normal, mu, 2.0 * PI * u[3]))
            }
        }
    }
}

impl Light {
    /// Radiant intensity per unit emitted power (per steradian) along unit `d` from the point `x`
    /// a photon started at: what a connection from the light to a point carries (0 for a beam,
    /// whose directions are a delta).
    pub fn intensity(&self, d: DVec3) -> f64 {
        match *self {
            Light::Beam { .. } | Light::FocusedBeam { .. } => 0.0,
            Light::Point { .. } => 1.0 / (4.0 * PI),
            Light::Spot {
                axis, half_angle, ..
            } => {
                if d.dot(axis) >= half_angle.cos() {
                    1.0 / (2.0 * PI * (1.0 - half_angle.cos()))
                } else {
                    0.0
                }
            }
            Light::Area { normal, .. } => d.dot(normal).max(0.0) / PI,
        }
    }

    /// The density a collimated beam draws its start points with, per unit area of its disc
    /// (what a connection from the beam to a point carries, as [`Self::intensity`] for a point
    /// source); 0 for other lights and for a beam of radius 0, a single ray no connection meets.
    pub fn beam_density(&self) -> f64 {
        match *self {
            Light::Beam { radius, .. } if radius > 0.0 => 1.0 / (PI * radius * radius),
            _ => 0.0,
        }
    }

    /// For a collimated beam of non-zero radius, where `p` lies about it: its distance along the
    /// beam from the disc's plane (negative upstream), its distance from the beam's axis, and the
    /// beam's radius.
    fn beam_coordinates(&self, p: DVec3) -> Option<(f64, f64, f64)> {
        match *self {
            Light::Beam {
                center,
                direction,
                radius,
            } if radius > 0.0 => {
                let along = (p - center).dot(direction);
                Some((along, (p - direction * along - center).length(), radius))
            }
            _ => None,
        }
    }

    /// Whether `p` lies near a collimated beam of non-zero radius: downstream of its disc and
    /// within its straight tube widened by [`BEAM_REACH`] per unit length along it (where
    /// bidirectional tracing tries to connect the beam to an event; see there).
    pub fn near_beam(&self, p: DVec3) -> bool {
        self.beam_coordinates(p)
            .is_some_and(|(along, off, radius)| along >= 0.0 && off <= radius + BEAM_REACH * along)
    }

    /// For a collimated beam of non-zero radius, the distance from `p` back along the beam to its
    /// disc, if the line from `p` against the beam's direction meets the disc (`p` downstream of
    /// it): the straight stretch a connection from the beam to a point ends with.
    pub fn beam_source(&self, p: DVec3) -> Option<f64> {
        let (along, off, radius) = self.beam_coordinates(p)?;
        (along >= 0.0 && off <= radius).then_some(along)
    }

    /// Where a path from a point joined to a beam of non-zero radius goes once it has left the
    /// volume: back along a collimated beam, or along the line through a focused beam's focus
    /// against the beam ([`Aim::Focus`]); `None` for other lights.
    pub fn beam_aim(&self) -> Option<Aim> {
        match *self {
            Light::Beam {
                center,
                direction,
                radius,
            } if radius > 0.0 => Some(Aim::Back {
                back: -direction,
                disc: center,
            }),
            Light::FocusedBeam {
                center,
                direction,
                radius,
                focus,
            } if radius > 0.0 => Some(Aim::Focus {
                focus,
                disc: center,
                direction,
            }),
            _ => None,
        }
    }

    /// A focused beam's intensity per unit emitted power at its focus along unit `d` (the
    /// direction of travel): its rays through the disc's area `A`, uniformly lit, are lines
    /// through the focus, so a ray starting `s` from the focus at `cos θ = d·direction` carries
    /// `s² / (A cos θ)` per solid angle there (0 off the disc, and for other lights). A focused
    /// beam is seen from outside the volume as a point light at its focus.
    pub fn focus_intensity(&self, d: DVec3) -> f64 {
        let Light::FocusedBeam {
            center,
            direction,
            radius,
            focus,
        } = *self
        else {
            return 0.0;
        };
        let cos = d.dot(direction);
        if radius <= 0.0 || cos <= 0.0 {
            return 0.0;
        }
        let s = (focus - center).dot(direction) / cos;
        if (focus - d * s - center).length() > radius {
            return 0.0;
        }
        s * s / (PI * radius * radius * cos)
    }

    /// The density the light draws the first segment of a photon starting at `x` along unit `d`
    /// with: per unit area of a collimated beam's disc, per solid angle at a focused beam's
    /// focus, per solid angle at other lights; and how the rays spread from there.
    pub fn start_density(&self, x: DVec3, d: DVec3) -> (f64, Rays) {
        match *self {
            Light::Beam { .. } => (self.beam_density(), Rays::Parallel),
            Light::FocusedBeam { focus, .. } => {
                (self.focus_intensity(d), Rays::Focused((focus - x).length()))
            }
            _ => (self.intensity(d), Rays::Spreading),
        }
    }

    /// The ray of a beam of non-zero radius that reaches `p` travelling along `−back` (given by
    /// [`Self::beam_aim`]), if it starts on the disc upstream of `p`: the distance back to the
    /// disc, the beam's density there ([`Self::start_density`]) and how its rays spread.
    pub fn beam_ray(&self, p: DVec3, back: DVec3) -> Option<BeamRay> {
        match *self {
            Light::Beam { .. } => Some(BeamRay {
                to_disc: self.beam_source(p)?,
                density: self.beam_density(),
                rays: Rays::Parallel,
            }),
            Light::FocusedBeam {
                center,
                direction,
                radius,
                focus,
            } if radius > 0.0 => {
                let cos = -back.dot(direction);
                let to_disc = (p - center).dot(direction) / cos;
                if !(cos > 0.0 && to_disc >= 0.0) {
                    return None;
                }
                let start = p + back * to_disc;
                if (start - center).length() > radius {
                    return None;
                }
                Some(BeamRay {
                    to_disc,
                    density: self.focus_intensity(-back),
                    rays: Rays::Focused((focus - start).length()),
                })
            }
            _ => None,
        }
    }
}

/// How the rays leaving the start of a segment spread, for the density of its end: from that
/// point (a point light, a scattering event), not at all (a collimated beam, an orthographic
/// camera), or through a focus this far along them (a focused beam's, from its disc).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Rays {
    Spreading,
    Parallel,
    Focused(f64),
}

impl Rays {
    /// The spread `dA⊥/dω` of the rays `length` along them (1 for parallel rays, whose density is
    /// per unit area).
    pub fn spread(self, length: f64) -> f64 {
        match self {
            Rays::Spreading => length * length,
            Rays::Parallel => 1.0,
            Rays::Focused(s) => (length - s) * (length - s),
        }
    }
}

/// A beam's ray through a point ([`Light::beam_ray`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BeamRay {
    pub to_disc: f64,
    pub density: f64,
    pub rays: Rays,
}

/// A fluence-rate probe at a point inside the volume: power per unit area arriving from all
/// directions, per unit emitted power, by next-event connections along curved rays from every
/// scattering event (and from the light, when it starts inside the volume).
#[derive(Clone, Debug, PartialEq)]
pub struct Probe {
    pub name: String,
    pub position: DVec3,
}

/// An orthographic camera outside the volume: the radiance travelling along unit `direction` (the
/// camera looks along `−direction`), averaged over each pixel of a rectangle in the image plane
/// through `center` (perpendicular to `direction`), per unit emitted power. Every scattering event
/// (and a light inside the volume) is connected to it by the path leaving the volume along
/// `direction`, refracted at the surface.
#[derive(Clone, Debug, PartialEq)]
pub struct Camera {
    pub name: String,
    pub direction: DVec3,
    pub center: DVec3,
    pub right: DVec3,
    pub up: DVec3,
    pub size: [f64; 2],
    pub pixels: [usize; 2],
    /// How the pixels share what arrives (box unless asked).
    pub filter: Filter,
    /// Windows of pixels summed as outputs of their own.
    pub windows: Vec<PixelWindow>,
}

impl Camera {
    pub fn new(
        name: String,
        direction: DVec3,
        center: DVec3,
        size: [f64; 2],
        pixels: [usize; 2],
    ) -> Self {
        let (right, up) = orthonormal_basis(direction);
        Camera {
            name,
            direction,
            center,
            right,
            up,
            size,
            pixels,
            filter: Filter::Box,
            windows: Vec::new(),
        }
    }

    /// Where light leaving the volume at `x` along the camera's direction lands on its image, as
    /// fractions of the rectangle's sides from its lower left corner (inside it within [0, 1)).
    pub fn fractions(&self, x: DVec3) -> (f64, f64) {
        let rel = x - self.center;
        (
            rel.dot(self.right) / self.size[0] + 0.5,
            rel.dot(self.up) / self.size[1] + 0.5,
        )
    }

    pub fn pixel_count(&self) -> usize {
        self.pixels[0] * self.pixels[1]
    }

    pub fn pixel_area(&self) -> f64 {
        self.area() / self.pixel_count() as f64
    }

    /// The area of the camera's rectangle.
    pub fn area(&self) -> f64 {
        self.size[0] * self.size[1]
    }

    /// The pixel (row-major from the lower left, `right` fastest) that light leaving the volume
    /// at `x` along the camera's direction lands in.
    pub fn pixel(&self, x: DVec3) -> Option<usize> {
        let (a, b) = self.fractions(x);
        if !(0.0..1.0).contains(&a) || !(0.0..1.0).contains(&b) {
            return None;
        }
        Some(grid_pixel(a, b, self.pixels))
    }
}

/// A pinhole camera outside the volume at `position`, looking along unit `forward` with `up`
/// (unit, ⟂ forward) and `right = forward × up`: each pixel holds the radiance arriving at the
/// pinhole, averaged over the pixel's area in the image plane at unit distance (`tan_half`: half
/// the image's extent there, per side). Every scattering event (and a light inside the volume) is
/// connected to the pinhole by the path leaving the volume and running straight through it.
#[derive(Clone, Debug, PartialEq)]
pub struct Pinhole {
    pub name: String,
    pub position: DVec3,
    pub forward: DVec3,
    pub up: DVec3,
    pub right: DVec3,
    pub tan_half: [f64; 2],
    pub pixels: [usize; 2],
    /// How the pixels share what arrives (box unless asked).
    pub filter: Filter,
    /// Windows of pixels summed as outputs of their own.
    pub windows: Vec<PixelWindow>,
}

impl Pinhole {
    /// A pinhole at `position` looking at `target`, `up` giving the image's vertical (made
    /// perpendicular), the vertical field of view `fov` (radians) and the pixel counts.
    pub fn looking_at(
        name: String,
        position: DVec3,
        target: DVec3,
        up: DVec3,
        fov: f64,
        pixels: [usize; 2],
    ) -> Option<Self> {
        let forward = (target - position).try_normalize()?;
        let up = (up - forward * up.dot(forward)).try_normalize()?;
        let right = forward.cross(up);
        let th = (0.5 * fov).tan();
        Some(Pinhole {
            name,
            position,
            forward,
            up,
            right,
            tan_half: [th * pixels[0] as f64 / pixels[1] as f64, th],
            pixels,
            filter: Filter::Box,
            windows: Vec::new(),
        })
    }

    pub fn pixel_count(&self) -> usize {
        self.pixels[0] * self.pixels[1]
    }

    /// The image plane's area at unit distance, seen per solid angle along a direction at
    /// cosine `cos` to the axis (`dω = cos³θ dA`): `cos³θ · 4 tan tan`.
    pub fn image_area(&self, cos: f64) -> f64 {
        cos * cos * cos * 4.0 * self.tan_half[0] * self.tan_half[1]
    }

    /// The area of one pixel in the image plane at unit distance.
    pub fn pixel_area(&self) -> f64 {
        4.0 * self.tan_half[0] * self.tan_half[1] / self.pixel_count() as f64
    }

    /// The pixel seeing light that arrives travelling along unit `d`, and the cosine of its angle
    /// to the axis.
    pub fn pixel(&self, d: DVec3) -> Option<(usize, f64)> {
        let (a, b, cos) = self.fractions(d)?;
        if !(0.0..1.0).contains(&a) || !(0.0..1.0).contains(&b) {
            return None;
        }
        Some((grid_pixel(a, b, self.pixels), cos))
    }

    /// Where light arriving along unit `d` lands on the image, as fractions of its sides from
    /// the lower left corner (inside it within [0, 1)), and the cosine of its angle to the axis;
    /// `None` from behind.
    pub fn fractions(&self, d: DVec3) -> Option<(f64, f64, f64)> {
        let v = -d;
        let cos = v.dot(self.forward);
        if cos <= 0.0 {
            return None;
        }
        let a = (v.dot(self.right) / cos / self.tan_half[0] + 1.0) * 0.5;
        let b = (v.dot(self.up) / cos / self.tan_half[1] + 1.0) * 0.5;
        Some((a, b, cos))
    }
}

/// How the index field changes in time as the light meets it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Modulation {
    /// The ultrasound oscillates (an ultrasonic amplitude as `n_max sin Ωt`, a phased array's
    /// pressure as `Re[P e^{−iΩt}]`) and the sensor integrates over whole periods
    /// (continuous-wave light): each photon meets the field at a uniformly random instant
    /// (paper 002, App. C, Eq. 22).
    Sinusoidal,
}

/// The most parameters a render differentiates at once.
pub const MAX_DERIVATIVES: usize = 16;

/// Targets a scene has at most.
pub const MAX_TARGETS: usize = 16;

/// How connections to probes are estimated.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Connections {
    /// One stationary path drawn at random, weighted by its estimated inverse probability
    /// (paper 002, Alg. 3): unbiased when several paths join two points.
    #[default]
    Unbiased,
    /// The first path Newton's method finds, unweighted: faster, and exact where only one path
    /// joins two points (biased where several do).
    First,
}

/// Which way paths are traced.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub enum Tracing {
    /// Particle tracing: photons from the light, connected to probes and cameras.
    #[default]
    FromLight,
    /// Path tracing: paths from the pinhole cameras, connected to the light.
    FromCameras,
    /// Bidirectional path tracing: a subpath from the light and one from each camera, joined
    /// every way, weighted by multiple importance sampling (sensor planes, probes and the light
    /// reaching surfaces from the light subpaths alone).
    Bidirectional,
}

/// What a sensor reports.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum SensorKind {
    /// The power crossing a plane away from the volume (total reflectance or transmittance).
    Flux,
    /// The irradiance on a rectangle of pixels (a bare sensor or a screen): power per pixel area.
    Screen,
    /// The mean fluence rate over a region inside the volume ([`Sensor::region`]): the light
    /// delivered there, by the photons' track lengths through it.
    Target,
    /// The power crossing a plane weighted by a Gaussian aperture about its centre
    /// ([`Sensor::aperture`]): the light a detector of Gaussian response collects, the focal
    /// spot of a relay lens. The weight falls smoothly to 0, so the output follows the light
    /// continuously as the field moves it.
    Spot,
}

/// A parameter a render is differentiated by.
#[derive(Clone, Debug, PartialEq)]
pub enum Derivative {
    /// A parameter of the homogeneous medium: path-space scores of every photon.
    Medium(MediumDerivative),
    /// A parameter of the index field: forward sensitivities of every photon's path (see
    /// [`super::tangent`]).
    Field(FieldDerivative),
}

/// A parameter of the index field a render is differentiated by.
#[derive(Clone, Debug, PartialEq)]
pub struct FieldDerivative {
    pub param: crate::eikonal::FieldParam,
    /// `profiles[i].name`, as configs name it.
    pub name: String,
    /// `∂(stored value)/∂(parameter)`: the sine of a strobe's phase for an ultrasonic profile's
    /// amplitude (the field holds `n_max sin Ωt`), else 1.
    pub scale: f64,
    /// Which of several volumes' profiles it is a parameter of (`volume[k].profiles[i].name`);
    /// `None` for the one volume's.
    pub volume: Option<usize>,
}

impl FieldDerivative {
    /// The profile it is a parameter of in `field`, and the shape it lies in (the part's, in
    /// the part's own coordinates, for one of several volumes).
    pub fn profile<'f>(&self, field: &'f BoundedField) -> Option<(&'f Profile, &'f Bounds)> {
        match self.volume {
            None => Some((field.profiles.get(self.param.profile)?, &field.bounds)),
            Some(k) => {
                let part = field.bounds.parts()?.get(k)?;
                Some((part.profiles.get(self.param.profile)?, &part.shape))
            }
        }
    }

    /// Its stored value in `field`.
    pub fn stored(&self, field: &BoundedField) -> Option<f64> {
        let mut profile = self.profile(field)?.0.clone();
        profile.param_mut(self.param.which).map(|x| *x)
    }

    /// Change its stored value in `field` by `change`.
    pub fn change(&self, field: &mut BoundedField, change: impl FnOnce(&mut f64)) {
        let which = self.param.which;
        match self.volume {
            None => {
                if let Some(x) = field
                    .profiles
                    .get_mut(self.param.profile)
                    .and_then(|p| p.param_mut(which))
                {
                    change(x);
                }
            }
            Some(k) => {
                let mut change = Some(change);
                field.change_parts(|j, part| {
                    if j == k
                        && let Some(x) = part
                            .profiles
                            .get_mut(self.param.profile)
                            .and_then(|p| p.param_mut(which))
                        && let Some(c) = change.take()
                    {
                        c(x);
                    }
                });
            }
        }
    }

    /// `(∂n/∂stored, ∇ ∂n/∂stored)` at `x` (scene coordinates, inside `field`'s bounds), the
    /// profile's scaled as `n` is ([`BoundedField::scale`], [`Part::scale`]); zero in the other
    /// volumes of several. `part`: the part holding `x` where the field is several
    /// ([`crate::eikonal::part_at`], found once per point by the caller for all parameters).
    #[inline]
    pub fn dn(&self, field: &BoundedField, x: DVec3, part: Option<usize>) -> (f64, DVec3) {
        let (p, which) = (self.param.profile, self.param.which);
        let (d, g, scale) = match (self.volume, field.bounds.parts()) {
            (Some(k), Some(parts)) => {
                if part != Some(k) {
                    return (0.0, DVec3::ZERO);
                }
                let part = &parts[k];
                let (d, g) = part.profiles[p]
                    .dparam(x - part.center, which)
                    .unwrap_or((0.0, DVec3::ZERO));
                (d, g, part.scale)
            }
            _ => {
                let (d, g) = field.profiles[p]
                    .dparam(x, which)
                    .unwrap_or((0.0, DVec3::ZERO));
                (d, g, field.scale)
            }
        };
        (d * scale, g * scale)
    }
}

/// A medium parameter a render is differentiated by, of the one volume or of one of several.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MediumDerivative {
    pub param: crate::medium::params::Param,
    /// Which of several volumes ([`Volume::parts`]) it belongs to; `None` for one volume.
    pub volume: Option<usize>,
}

impl MediumDerivative {
    /// `param` of the one volume.
    pub fn of_one(param: crate::medium::params::Param) -> Self {
        MediumDerivative {
            param,
            volume: None,
        }
    }

    /// `sigma_s`, or `volume[1].sigma_s` for one of several volumes.
    pub fn name(&self) -> String {
        match self.volume {
            None => self.param.name(),
            Some(k) => format!("volume[{k}].{}", self.param.name()),
        }
    }
}

impl Derivative {
    pub fn name(&self) -> String {
        match self {
            Derivative::Medium(m) => m.name(),
            Derivative::Field(f) => f.name.clone(),
        }
    }

    /// The medium parameter, if this is one.
    pub fn medium(&self) -> Option<MediumDerivative> {
        match self {
            Derivative::Medium(m) => Some(*m),
            Derivative::Field(_) => None,
        }
    }

    /// The medium parameter, if this is one of the medium in `part` ([`Volume::part_index`]:
    /// `None` for one volume): what scores an event there.
    #[inline]
    pub fn medium_in(&self, part: Option<usize>) -> Option<crate::medium::params::Param> {
        match self {
            Derivative::Medium(m) if m.volume == part => Some(m.param),
            _ => None,
        }
    }
}

/// The geometric lengths of a path inside the volume, part by part where it is several (at 0
/// for one volume): what the attenuation along it and its derivatives take.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct PartLengths([f64; crate::eikonal::MAX_PARTS]);

impl PartLengths {
    /// `length` inside `part` alone (`None`: the one volume).
    pub fn one(part: Option<usize>, length: f64) -> Self {
        let mut lengths = PartLengths::default();
        lengths.add(part, length);
        lengths
    }

    /// Add `length` inside `part` (`None`: the one volume).
    #[inline]
    pub fn add(&mut self, part: Option<usize>, length: f64) {
        self.0[part.unwrap_or(0)] += length;
    }

    /// The length inside `part`; for `None`, inside the whole volume.
    pub fn within(&self, part: Option<usize>) -> f64 {
        part.map_or_else(|| self.total(), |k| self.0[k])
    }

    pub fn total(&self) -> f64 {
        self.0.iter().sum()
    }

    /// `∫σ_t` along the path in a homogeneous `volume`: each part's length at its `σ_t`.
    pub fn depth(&self, volume: &Volume) -> f64 {
        if volume.parts.is_empty() {
            return volume.sigma_t() * self.0[0];
        }
        (volume.parts.iter().zip(&self.0))
            .map(|(b, l)| b.sigma_t() * l)
            .sum()
    }
}

/// A target region inside the volume.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Region {
    Sphere {
        center: DVec3,
        radius: f64,
    },
    /// An axis-aligned box of half-sides `half`.
    Box {
        center: DVec3,
        half: DVec3,
    },
}

impl Region {
    pub fn volume(&self) -> f64 {
        match *self {
            Region::Sphere { radius, .. } => 4.0 / 3.0 * std::f64::consts::PI * radius.powi(3),
            Region::Box { half, .. } => 8.0 * half.x * half.y * half.z,
        }
    }

    pub fn center(&self) -> DVec3 {
        match *self {
            Region::Sphere { center, .. } | Region::Box { center, .. } => center,
        }
    }

    /// A normal of the region's surface at `x` on it (not unit): the direction its boundary
    /// moves a crossing point along.
    #[inline]
    pub fn normal(&self, x: DVec3) -> DVec3 {
        match *self {
            Region::Sphere { center, .. } => x - center,
            Region::Box { center, half } => {
                let r = (x - center) / half;
                let a = r.abs().max_position();
                let mut n = DVec3::ZERO;
                n[a] = r[a].signum();
                n
            }
        }
    }

    /// The part `[t0, t1] ⊂ [0, 1]` of the segment `a + t (b − a)` inside the region, if any.
    #[inline]
    pub fn clip(&self, a: DVec3, b: DVec3) -> Option<(f64, f64)> {
        let d = b - a;
        let (t0, t1) = match *self {
            Region::Sphere { center, radius } => {
                let o = a - center;
                let dd = d.length_squared();
                if dd == 0.0 {
                    return None;
                }
                let half_b = o.dot(d) / dd;
                let c = (o.length_squared() - radius * radius) / dd;
                let disc = half_b * half_b - c;
                if disc <= 0.0 {
                    return None;
                }
                let root = disc.sqrt();
                (-half_b - root, -half_b + root)
            }
            Region::Box { center, half } => {
                let (lo, hi) = (center - half - a, center + half - a);
                let (mut t0, mut t1) = (f64::NEG_INFINITY, f64::INFINITY);
                for k in 0..3 {
                    if d[k] == 0.0 {
                        if lo[k] > 0.0 || hi[k] < 0.0 {
                            return None;
                        }
                        continue;
                    }
                    let (u, v) = (lo[k] / d[k], hi[k] / d[k]);
                    t0 = t0.max(u.min(v));
                    t1 = t1.min(u.max(v));
                }
                (t0, t1)
            }
        };
        let (t0, t1) = (t0.max(0.0), t1.min(1.0));
        (t1 > t0).then_some((t0, t1))
    }
}

/// How a screen's pixels share a crossing.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum Filter {
    /// All to the pixel it falls in.
    #[default]
    Box,
    /// Bilinearly to the four pixels whose centres surround it (a tent one pixel wide each way):
    /// each pixel's share falls continuously to 0, so the image follows the light continuously
    /// as the field moves it. The footprint reaches half a pixel beyond the rectangle, and the
    /// image is the irradiance convolved with the tent.
    Tent,
}

/// The pixels one crossing adds to: `(pixel, share, ∂share/∂p)`, `p` the crossing on the plane.
pub type Splat = ([(usize, f64, DVec3); 4], usize);

/// A plane outside the volume that records the light crossing it after the light has left the
/// volume (straight rays, index `n_out`): whole (a flux sensor without a size) or as pixels.
#[derive(Clone, Debug, PartialEq)]
pub struct Sensor {
    pub name: String,
    pub kind: SensorKind,
    pub center: DVec3,
    /// Unit normal pointing away from the volume: light is counted crossing along it.
    pub normal: DVec3,
    /// Unit vectors along the rectangle's sides (`up = normal × right`).
    pub right: DVec3,
    pub up: DVec3,
    /// Side lengths; `None`: the whole plane (flux sensors only).
    pub size: Option<[f64; 2]>,
    /// Pixel counts along `right` and `up` (`[1, 1]` for flux sensors).
    pub pixels: [usize; 2],
    /// Light is counted only within this angle of the normal (radians; a detector behind a
    /// collimator); `None`: every direction.
    pub acceptance: Option<f64>,
    /// A target's region (`None` for the planes).
    pub region: Option<Region>,
    /// A spot's Gaussian aperture: the `1/e²` radius `w` of its weight `exp(−2ρ²/w²)`, `ρ` the
    /// crossing's distance from `center` (`None` for the other kinds).
    pub window: Option<f64>,
    /// How a screen's pixels share a crossing.
    pub filter: Filter,
}

impl Sensor {
    /// A sensor facing away from the volume: `normal` is flipped if it points towards it.
    pub fn new(
        name: String,
        kind: SensorKind,
        center: DVec3,
        normal: DVec3,
        size: Option<[f64; 2]>,
        pixels: [usize; 2],
    ) -> Self {
        let normal = if normal.dot(center) < 0.0 {
            -normal
        } else {
            normal
        };
        let (right, up) = orthonormal_basis(normal);
        Sensor {
            name,
            kind,
            center,
            normal,
            right,
            up,
            size,
            pixels,
            acceptance: None,
            region: None,
            window: None,
            filter: Filter::Box,
        }
    }

    /// Whether what the sensor records changes continuously as the light it receives moves
    /// (targets, spots, tent-filtered screens; not a flux plane's or a box-filtered pixel's
    /// edges), as index-field derivatives need.
    pub fn follows_light_continuously(&self) -> bool {
        match self.kind {
            SensorKind::Target | SensorKind::Spot => true,
            SensorKind::Screen => self.filter == Filter::Tent,
            SensorKind::Flux => false,
        }
    }

    /// The weight of a crossing at `at` on the plane: a spot's Gaussian aperture
    /// `exp(−2ρ²/w²)`, 1 for the other sensors.
    #[inline]
    pub fn aperture(&self, at: DVec3) -> f64 {
        match self.window {
            Some(w) => (-2.0 * (at - self.center).length_squared() / (w * w)).exp(),
            None => 1.0,
        }
    }

    /// The gradient of [`Self::aperture`] at `at` (in the plane: `at − center` lies in it).
    #[inline]
    pub fn aperture_gradient(&self, at: DVec3) -> DVec3 {
        match self.window {
            Some(w) => (at - self.center) * (-4.0 / (w * w)) * self.aperture(at),
            None => DVec3::ZERO,
        }
    }

    /// A target: the mean fluence rate over `region`, inside the volume.
    pub fn target(name: String, region: Region) -> Self {
        Sensor {
            region: Some(region),
            ..Sensor::new(
                name,
                SensorKind::Target,
                region.center(),
                DVec3::Z,
                None,
                [1, 1],
            )
        }
    }

    pub fn pixel_count(&self) -> usize {
        self.pixels[0] * self.pixels[1]
    }

    /// Where the straight ray `x + t d` (after it left the volume) crosses the sensor's plane
    /// within its acceptance cone: the distance `t`.
    #[inline]
    pub fn crossing(&self, x: DVec3, d: DVec3) -> Option<f64> {
        if self.kind == SensorKind::Target {
            return None;
        }
        let cos = d.dot(self.normal);
        if cos <= 0.0 || self.acceptance.is_some_and(|a| cos < a.cos()) {
            return None;
        }
        let t = (self.center - x).dot(self.normal) / cos;
        // a ray leaving the volume on the plane itself (a sensor on a face) counts
        if t < -1e-9 * (1.0 + self.center.length()) {
            return None;
        }
        Some(t.max(0.0))
    }

    /// Where the crossing at `p` on the plane lies across the rectangle, as fractions of its
    /// sides from its lower left corner (`None` for a whole plane).
    #[inline]
    fn fractions(&self, p: DVec3) -> Option<(f64, f64)> {
        let size = self.size?;
        let rel = p - self.center;
        Some((
            rel.dot(self.right) / size[0] + 0.5,
            rel.dot(self.up) / size[1] + 0.5,
        ))
    }

    /// The pixel a crossing at `p` on the plane falls in (row-major from the lower left, `right`
    /// fastest; 0 on a whole plane; `None` off the rectangle).
    #[inline]
    pub fn pixel_at(&self, p: DVec3) -> Option<usize> {
        let Some((a, b)) = self.fractions(p) else {
            return Some(0);
        };
        ((0.0..1.0).contains(&a) && (0.0..1.0).contains(&b)).then(|| grid_pixel(a, b, self.pixels))
    }

    /// The pixels of a tent-filtered screen a crossing at `p` adds to, with their shares and
    /// the shares' gradients along the plane (none outside the footprint).
    #[inline]
    pub fn splat(&self, p: DVec3) -> Splat {
        let mut splat = ([(0, 0.0, DVec3::ZERO); 4], 0);
        let (Some((a, b)), Some(size)) = (self.fractions(p), self.size) else {
            return splat;
        };
        let (t, count) = tent(a, b, self.pixels);
        for (o, &(pixel, share, [ga, gb])) in splat.0.iter_mut().zip(&t[..count]) {
            *o = (
                pixel,
                share,
                self.right * (ga / size[0]) + self.up * (gb / size[1]),
            );
        }
        splat.1 = count;
        splat
    }

    /// The area of one pixel (`None` for an unbounded plane).
    pub fn pixel_area(&self) -> Option<f64> {
        self.size
            .map(|s| s[0] * s[1] / (self.pixels[0] * self.pixels[1]) as f64)
    }
}

/// A diffuse (Lambertian) or black surface outside the volume: a plane, or a rectangle of `size`
/// about `center` (a floor, a tank wall). Both sides reflect `albedo` of the light reaching them,
/// uniformly in radiance; the rest is absorbed.
#[derive(Clone, Debug, PartialEq)]
pub struct Surface {
    pub name: String,
    pub center: DVec3,
    /// Unit normal; `right` and `up` span the rectangle (`up = normal × right`).
    pub normal: DVec3,
    pub right: DVec3,
    pub up: DVec3,
    /// Side lengths; `None`: the whole plane.
    pub size: Option<[f64; 2]>,
    pub albedo: f64,
}

impl Surface {
    pub fn new(
        name: String,
        center: DVec3,
        normal: DVec3,
        size: Option<[f64; 2]>,
        albedo: f64,
    ) -> Self {
        let (right, up) = orthonormal_basis(normal);
        Surface {
            name,
            center,
            normal,
            right,
            up,
            size,
            albedo,
        }
    }

    /// The distance along unit `d` from `x` to the surface, if the ray meets it ahead (a start on
    /// the surface itself does not count).
    #[inline]
    pub fn hit(&self, x: DVec3, d: DVec3) -> Option<f64> {
        let cos = d.dot(self.normal);
        if cos == 0.0 {
            return None;
        }
        let t = (self.center - x).dot(self.normal) / cos;
        // (a NaN distance fails too)
        if t.is_nan() || t <= 1e-9 * (1.0 + (x - self.center).length()) {
            return None;
        }
        if let Some(size) = self.size {
            let rel = x + d * t - self.center;
            if rel.dot(self.right).abs() > 0.5 * size[0] || rel.dot(self.up).abs() > 0.5 * size[1] {
                return None;
            }
        }
        Some(t)
    }
}

/// Time-of-flight bins: optical path lengths `∫ n ds` from the light, in `bins` equal bins over
/// `[0, max_path)` (paper 002, Eq. 14); light arriving later is not recorded.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Transient {
    pub bins: usize,
    pub max_path: f64,
}

/// A refractive render: the volume, its light, the sensors, and how rays are stepped.
#[derive(Clone, Debug, PartialEq)]
pub struct RenderScene {
    pub volume: Volume,
    pub light: Light,
    pub sensors: Vec<Sensor>,
    pub probes: Vec<Probe>,
    pub cameras: Vec<Camera>,
    pub pinholes: Vec<Pinhole>,
    /// Diffuse or black surfaces outside the volume.
    pub surfaces: Vec<Surface>,
    /// `None`: the field is static.
    pub modulation: Option<Modulation>,
    pub connections: Connections,
    /// Reflections inside the volume's surface a connection through it follows at most before
    /// it leaves (specular chains: light leaving the glass after reflecting inside it).
    pub reflections: usize,
    /// Parameters of the medium or the index field whose derivatives particle tracing estimates
    /// for every sensor's power (at most [`MAX_DERIVATIVES`]).
    pub derivatives: Vec<Derivative>,
    pub tracing: Tracing,
    pub transient: Option<Transient>,
    /// `None`: one unnamed wavelength, the field as given.
    pub spectrum: Option<super::spectrum::Spectrum>,
    /// Leapfrog step in the σ-form (geometric length ≈ `n · step`), where `n` varies.
    pub step: f64,
    /// Most leapfrog steps of one free flight.
    pub max_steps: usize,
}

impl RenderScene {
    /// The names of what a render operation outputs, in order: every sensor's power (a target's
    /// fluence), every probe's fluence rate, then every camera window's sum.
    pub fn objectives(&self) -> Vec<String> {
        let sensors = self.sensors.iter().map(|s| s.name.clone());
        let windows = (0..self.cameras.len() + self.pinholes.len())
            .flat_map(|c| self.camera_windows(c).iter().map(|w| w.name.clone()));
        sensors
            .chain(self.probes.iter().map(|p| p.name.clone()))
            .chain(windows)
            .collect()
    }

    /// The pixel windows of camera `i` (the orthographic cameras first, then the pinholes).
    pub fn camera_windows(&self, i: usize) -> &[PixelWindow] {
        match self.cameras.get(i) {
            Some(c) => &c.windows,
            None => &self.pinholes[i - self.cameras.len()].windows,
        }
    }

    /// The width and height in pixels of camera `i`'s image (the orthographic cameras first).
    pub fn camera_pixels(&self, i: usize) -> [usize; 2] {
        match self.cameras.get(i) {
            Some(c) => c.pixels,
            None => self.pinholes[i - self.cameras.len()].pixels,
        }
    }

    /// Whether any derivative is with respect to the index field.
    pub fn field_derivatives(&self) -> bool {
        self.derivatives
            .iter()
            .any(|d| matches!(d, Derivative::Field(_)))
    }

    /// Time bins per pixel (1 without a transient).
    pub fn bins(&self) -> usize {
        self.transient.map_or(1, |t| t.bins)
    }

    /// The nearest surface the straight ray from `x` along unit `d` meets, and its distance.
    pub fn surface_hit(&self, x: DVec3, d: DVec3) -> Option<(usize, f64)> {
        self.surfaces
            .iter()
            .enumerate()
            .filter_map(|(i, s)| s.hit(x, d).map(|t| (i, t)))
            .min_by(|a, b| a.1.total_cmp(&b.1))
    }

    /// Whether the straight segment from `x` along unit `d` for `length` (outside the volume)
    /// is blocked by a surface.
    pub fn blocked(&self, x: DVec3, d: DVec3, length: f64) -> bool {
        self.surfaces
            .iter()
            .any(|s| s.hit(x, d).is_some_and(|t| t < length))
    }

    /// Colour channels of screen and camera images (3 for a white spectrum, else 1).
    pub fn channels(&self) -> usize {
        self.spectrum.as_ref().map_or(1, |s| s.channels())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A focused beam's intensity at its focus integrates to its power over the directions of
    /// its rays (a tilted cone: the focus off the disc's axis), by quadrature over the sphere;
    /// without the `1/cos θ` of its disc seen obliquely it would come to 0.94.
    #[test]
    fn a_focused_beams_intensity_integrates_to_its_power() {
        let light = Light::FocusedBeam {
            center: DVec3::new(0.2, -0.1, -3.0),
            direction: DVec3::new(0.3, 0.0, 1.0).normalize(),
            radius: 1.2,
            focus: DVec3::new(0.5, 0.4, 0.5),
        };
        let (a, b) = orthonormal_basis(DVec3::Z);
        let (n_theta, n_phi) = (3000, 1000);
        let (d_theta, d_phi) = (PI / n_theta as f64, 2.0 * PI / n_phi as f64);
        let mut total = 0.0;
        for i in 0..n_theta {
            let theta = (i as f64 + 0.5) * d_theta;
            for j in 0..n_phi {
                let phi = (j as f64 + 0.5) * d_phi;
                let d = DVec3::Z * theta.cos() + (a * phi.cos() + b * phi.sin()) * theta.sin();
                total += light.focus_intensity(d) * theta.sin() * d_theta * d_phi;
            }
        }
        assert!((total - 1.0).abs() < 2e-3, "{total}");
        // other lights have none
        let point = Light::Point {
            position: DVec3::ZERO,
        };
        assert_eq!(point.focus_intensity(DVec3::Z), 0.0);
    }
}
