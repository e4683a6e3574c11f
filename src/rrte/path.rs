//! Path tracing from the cameras: the same images as particle tracing, estimated backwards.
//!
//! A path starts at a pinhole through a uniformly drawn point of a uniformly drawn pixel (or at
//! such a point of an orthographic camera's rectangle, looking back along its direction), runs
//! straight to the volume or a surface, refracts or reflects at the volume's surface with the
//! Fresnel probabilities, flies along curved rays over geometric length (delta tracking through a
//! density), and scatters by the phase function (or diffusely off a surface) carrying the albedo.
//! At every scattering event the light is connected to it: through the volume by a boundary-value
//! connection (a curved ray to a light inside, or a ray leaving the volume and running straight to
//! a light outside, solved as in [`super::connect`]); to a surface from a light outside in a
//! straight line, across the volume (refracted in and out: the caustics it throws) and off its
//! outside (reflected: the light's mirror image thrown on the surface), or from a
//! light inside through the volume's surface.
//!
//! The estimate is carried in basic radiance `B = L/n²`, which the RRTE conserves along rays and
//! transmits across an interface as `(1 − R) B` (paper 002, Table 1): no `n²` appears along the
//! path. A point source of intensity `I` at `q` gives the event at `x` the irradiance
//! `I T (1 − R) n_x² / (n_q² dA_q/dω_x)`, where `dA_q/dω_x` is the ray tube's cross-section at `q`
//! per solid angle at `x` that the connection solves for (reciprocity of the two-point étendue,
//! `n_x² dA_x dω_x = n_q² dA_q dω_q`); in basic radiance the `n_x²` cancels. The camera sees
//! `L = n_out² B`.
//!
//! A collimated beam is joined to an event by the path leaving it back along the beam to the
//! beam's disc (an orthographic camera's connection run the other way); a focused beam, whose
//! rays outside the volume are the lines through its focus, as a point light there, by the path
//! leaving along the line through the focus (which may lie behind where it leaves). A light
//! inside the volume is
//! connected to the cameras directly, as in particle tracing, and one outside is not imaged
//! itself (nor its mirror image in the volume). The connections reflect inside the surface at
//! most `render.reflections` times, so light that reaches its first scattering event only after
//! more reflections is missed (particle tracing misses the mirror case, light leaving its last event so): with
//! index-matched surfaces the two estimate the same images.

use super::connect::{Aim, Exit};
use super::particle::{Leg, ParticleTracer, Reflections, Stop, Tools, Way};
use super::scene::{Light, PartLengths, Rays, grid_pixel};
use crate::eikonal::Ray;
use crate::math::{C64, Rng, uniform};
use glam::DVec3;
use std::f64::consts::PI;

/// A camera path's state: throughput in basic radiance, optical path from the camera, counts.
struct Walk {
    beta: f64,
    opl: f64,
    events: usize,
    steps: usize,
}

impl Walk {
    /// Russian roulette once the throughput is small: `false` if the path ends.
    fn roulette(&mut self, rng: &mut Rng) -> bool {
        super::particle::roulette(&mut self.beta, rng)
    }
}

/// What a camera path adds to its pixel: radiance samples in their time bins.
pub(super) struct Pixel {
    /// The camera (the orthographic cameras first, then the pinholes).
    pub(super) camera: usize,
    image: super::ImageLayout,
    pixel: usize,
    /// Pixels of the camera: a uniformly drawn pixel's sample counts this many times.
    count: f64,
    /// Turns a radiance sample into the camera's total: `cos³θ` times the image-plane area for a
    /// pinhole (the irradiance from its field of view), the pixel count for an orthographic
    /// camera (the sum of its pixels).
    to_total: f64,
    /// The density the ray was drawn with: per solid angle at a pinhole, per unit area of an
    /// orthographic camera's rectangle.
    pub(super) pdf: f64,
}

/// A connection from the light to an event inside the volume (see
/// [`ParticleTracer::light_link`]).
pub(super) struct LightLink {
    /// Unit direction leaving the event towards the light.
    pub(super) direction: DVec3,
    /// The radiance it brings to the camera per unit throughput and phase function.
    pub(super) radiance: f64,
    /// Group delay from the light to the event.
    pub(super) delay: f64,
    /// Geometric length inside the volume (part by part) and straight outside it.
    pub(super) inside: PartLengths,
    pub(super) outside: f64,
    /// The light's own density of emitting along the path (per solid angle; per unit area of a
    /// collimated beam's disc), and how its rays spread from where they start.
    pub(super) pdf: f64,
    pub(super) rays: Rays,
}

impl ParticleTracer<'_> {
    /// One camera path per camera, adding its radiance samples to `out`; and, for a light inside
    /// the volume, its direct light connected to the cameras as particle tracing does (a point
    /// cannot be hit by a path).
    pub(super) fn camera_paths(&self, t: &Tools, rng: &mut Rng, out: &mut [C64]) {
        let scene = self.scene;
        if let Some(q) = self.light_point(rng)
            && t.flyer.volume.field.bounds.contains(q)
        {
            let light = &scene.light;
            self.connect(t, q, 1.0, 0.0, |d| light.intensity(d), rng, out);
        }
        // the pinholes first, then the orthographic cameras
        let orthographic = scene.cameras.len();
        let order = (orthographic..orthographic + scene.pinholes.len()).chain(0..orthographic);
        for camera in order {
            let (x, d, pixel) = self.camera_ray(camera, rng);
            self.camera_path(t, x, d, &pixel, rng, out);
        }
    }

    /// The start of a path from camera `camera` (the orthographic cameras first, then the
    /// pinholes, as in [`super::particle::CameraLink`]): a uniform point of a uniform pixel of a
    /// pinhole's image plane at unit distance, the ray through it; or of an orthographic camera's
    /// rectangle, looking back along the light.
    pub(super) fn camera_ray(&self, camera: usize, rng: &mut Rng) -> (DVec3, DVec3, Pixel) {
        let scene = self.scene;
        let (a, b) = (uniform(rng), uniform(rng));
        if let Some(cam) = scene.cameras.get(camera) {
            let y = cam.center
                + cam.right * ((a - 0.5) * cam.size[0])
                + cam.up * ((b - 0.5) * cam.size[1]);
            let count = cam.pixel_count() as f64;
            let pixel = Pixel {
                camera,
                image: self.camera_image(camera),
                pixel: grid_pixel(a, b, cam.pixels),
                count,
                to_total: count,
                pdf: 1.0 / cam.area(),
            };
            return (y, -cam.direction, pixel);
        }
        let i = camera - scene.cameras.len();
        let cam = &scene.pinholes[i];
        let v = cam.forward
            + cam.right * ((2.0 * a - 1.0) * cam.tan_half[0])
            + cam.up * ((2.0 * b - 1.0) * cam.tan_half[1]);
        let d = v.normalize();
        let cos = d.dot(cam.forward);
        let image_area = cam.image_area(cos);
        let pixel = Pixel {
            camera,
            image: self.pinhole_image(i),
            pixel: grid_pixel(a, b, cam.pixels),
            count: cam.pixel_count() as f64,
            to_total: image_area,
            pdf: 1.0 / image_area,
        };
        (cam.position, d, pixel)
    }

    /// Record the radiance sample `radiance` (at the camera) arriving with optical path `opl`;
    /// what it added to the camera's total.
    pub(super) fn record_sample(
        &self,
        t: &Tools,
        p: &Pixel,
        radiance: f64,
        opl: f64,
        out: &mut [C64],
    ) -> f64 {
        if !(radiance > 0.0 && radiance.is_finite()) {
            return 0.0;
        }
        let Some(bin) = self.bin(opl) else {
            return 0.0;
        };
        p.image
            .add(out, bin, p.pixel, radiance * p.count, &t.colour);
        let total = radiance * p.to_total;
        out[p.image.total()].re += total;
        self.add_to_windows(p.camera, p.pixel, total, self.windows, out);
        total
    }

    /// Trace the camera path leaving `x` along unit `d` (outside the volume).
    fn camera_path(
        &self,
        t: &Tools,
        x: DVec3,
        d: DVec3,
        pixel: &Pixel,
        rng: &mut Rng,
        out: &mut [C64],
    ) {
        let mut w = Walk {
            beta: 1.0,
            opl: 0.0,
            events: 0,
            steps: 0,
        };
        let mut leg = Leg::Outside {
            x,
            d,
            left_volume: false,
        };
        loop {
            let next = match leg {
                Leg::Inside(ray) => self.camera_inside(t, ray, &mut w, pixel, rng, out),
                Leg::Outside { x, d, left_volume } => {
                    self.camera_outside(t, x, d, left_volume, &mut w, pixel, rng, out)
                }
            };
            match next {
                Some(l) => leg = l,
                None => break,
            }
        }
        out[self.total(super::Total::Events)].re += w.events as f64;
        out[self.total(super::Total::Steps)].re += w.steps as f64;
    }

    /// A straight leg of the camera path outside the volume: into the volume (Fresnel), onto a
    /// surface (a diffuse event, connected to the light), or away.
    #[allow(clippy::too_many_arguments)]
    fn camera_outside(
        &self,
        t: &Tools,
        x: DVec3,
        d: DVec3,
        left_volume: bool,
        w: &mut Walk,
        pixel: &Pixel,
        rng: &mut Rng,
        out: &mut [C64],
    ) -> Option<Leg> {
        let n_out = t.flyer.volume.field.n_out;
        match self.ahead(t, x, d, left_volume) {
            (Some(t0), s) if s.is_none_or(|(_, ts)| t0 <= ts) => {
                w.opl += t.delay.outside(n_out * t0);
                Some(Leg::enter(t, x, d, t0, rng))
            }
            (_, Some((i, distance))) => {
                let s = &self.scene.surfaces[i];
                let y = x + d * distance;
                w.opl += t.delay.outside(n_out * distance);
                if s.albedo <= 0.0 {
                    return None;
                }
                w.beta *= s.albedo;
                w.events += 1;
                let facing = if d.dot(s.normal) < 0.0 {
                    s.normal
                } else {
                    -s.normal
                };
                self.light_to_surface(t, y, facing, w, pixel, rng, out);
                if !w.roulette(rng) {
                    return None;
                }
                let mu = uniform(rng).sqrt();
                let dir = crate::math::direction_about(facing, mu, 2.0 * PI * uniform(rng));
                Some(Leg::Outside {
                    x: y,
                    d: dir,
                    left_volume: false,
                })
            }
            _ => None,
        }
    }

    /// Connect the light to the lit point `y` of a surface: Lambertian radiance `albedo E / π`.
    #[allow(clippy::too_many_arguments)]
    fn light_to_surface(
        &self,
        t: &Tools,
        y: DVec3,
        facing: DVec3,
        w: &Walk,
        pixel: &Pixel,
        rng: &mut Rng,
        out: &mut [C64],
    ) {
        for way in self.ways(t, true) {
            let Some(link) = self.surface_light_link(t, y, facing, way, rng, out) else {
                continue;
            };
            // the surface's albedo is already in β: the Lambertian BRDF's 1/π remains
            self.record_sample(
                t,
                pixel,
                w.beta * link.radiance / PI,
                w.opl + link.delay,
                out,
            );
        }
    }

    /// The connection from the light to the lit point `y` of a surface (unit `facing` normal on
    /// the lit side); its `radiance` is the irradiance it brings to `y`. From a light outside, a
    /// straight line past no other surface (through the volume only where it is index-matched):
    /// `I T cos θ / d²`, or across the volume (refracted in and out, unscattered: a caustic)
    /// `I T (1 − R_in)(1 − R_out) cos θ / (dA⊥/dω)`, the ray tube's cross-section at the light
    /// per solid angle at `y` turned round by reciprocity (both ends in `n_out`); from a light
    /// inside, a connection through the volume's surface (see [`super::connect`]), after the
    /// `way`'s reflections inside it: `I T (1 − R) cos θ / (dA⊥/dω)`.
    pub(super) fn surface_light_link(
        &self,
        t: &Tools,
        y: DVec3,
        facing: DVec3,
        way: Way,
        rng: &mut Rng,
        out: &mut [C64],
    ) -> Option<LightLink> {
        if let Some(aim) = self.scene.light.beam_aim() {
            return self.surface_beam_link(t, y, facing, aim, way, rng, out);
        }
        let volume = t.flyer.volume;
        let n_out = volume.field.n_out;
        let light = &self.scene.light;
        let q = self.light_point(rng)?;
        let inside = volume.field.bounds.contains(q);
        if matches!(way, Way::Across | Way::Mirror) && !inside {
            let (e, carried) = self.across(t, y, Aim::Point(q), way, rng, out)?;
            let cos = e.direction.dot(facing);
            let to_q = (q - e.surface).dot(e.outgoing);
            if cos <= 0.0 || self.scene.blocked(e.surface, e.outgoing, to_q) {
                return None;
            }
            let intensity = light.intensity(-e.outgoing);
            let outside = n_out * (e.outside() + to_q);
            return Some(LightLink {
                direction: e.direction,
                radiance: intensity * cos * carried,
                delay: t.exit_delay(&e, outside),
                inside: e.lengths(volume),
                outside: e.outside() + to_q,
                pdf: intensity,
                rays: Rays::Spreading,
            });
        }
        if inside {
            let Way::Bounces(bounces) = way else {
                return None;
            };
            let o = self.out_to_surface(t, q, y, facing, bounces, rng, out)?;
            let intensity = light.intensity(o.exit.direction);
            return Some(LightLink {
                direction: -o.exit.outgoing,
                radiance: intensity * o.carried * o.cos,
                delay: o.delay,
                inside: o.exit.lengths(volume),
                outside: o.outside,
                pdf: intensity,
                rays: Rays::Spreading,
            });
        }
        if way != Way::Bounces(0) {
            return None;
        }
        let v = q - y;
        let distance = v.length();
        let dir = v / distance;
        let cos = dir.dot(facing);
        if cos <= 0.0 || self.scene.blocked(y, dir, distance) {
            return None;
        }
        let (transmittance, inside) = self.past_volume(t, y, dir, distance, rng)?;
        let intensity = light.intensity(-dir);
        Some(LightLink {
            direction: dir,
            radiance: intensity * cos * transmittance / (distance * distance),
            delay: t.delay.outside(n_out * distance),
            inside,
            outside: distance - inside.total(),
            pdf: intensity,
            rays: Rays::Spreading,
        })
    }

    /// A point of the light to connect to (`None` for a beam).
    pub(super) fn light_point(&self, rng: &mut Rng) -> Option<DVec3> {
        match self.scene.light {
            Light::Beam { .. } | Light::FocusedBeam { .. } => None,
            Light::Point { position } | Light::Spot { position, .. } => Some(position),
            Light::Area { .. } => {
                let (x, _) = self
                    .scene
                    .light
                    .sample([uniform(rng), uniform(rng), 0.5, 0.5]);
                Some(x)
            }
        }
    }

    /// Connect the light to the scattering event at `x` inside the volume, where the camera path
    /// arrived travelling along unit `u`; `beta` already holds the albedo.
    #[allow(clippy::too_many_arguments)]
    fn light_to_event(
        &self,
        t: &Tools,
        x: DVec3,
        u: DVec3,
        w: &Walk,
        pixel: &Pixel,
        rng: &mut Rng,
        out: &mut [C64],
    ) {
        for way in self.ways(t, false) {
            let Some(link) = self.light_link(t, x, way, false, rng, out) else {
                continue;
            };
            let phase = t.flyer.volume.scattering_at(x).eval(link.direction.dot(u));
            self.record_sample(
                t,
                pixel,
                w.beta * phase * link.radiance,
                w.opl + link.delay,
                out,
            );
        }
    }

    /// The connection from the light to `x` inside the volume: the basic radiance it brings to
    /// `x` per unit phase function, times the camera's `n_out²` (see the module's notes); after
    /// the `way`'s reflections inside the surface of `x`'s volume and inside the parts it meets
    /// (on a path that leaves it — from a light in another of several volumes, or around a part
    /// that is not convex — only one that fits [`super::connect::MAX_AGAIN`] from either end
    /// where `either_end`, as bidirectional tracing's weights count it).
    pub(super) fn light_link(
        &self,
        t: &Tools,
        x: DVec3,
        way: Way,
        either_end: bool,
        rng: &mut Rng,
        out: &mut [C64],
    ) -> Option<LightLink> {
        let Way::Bounces(bounces) = way else {
            return None;
        };
        if let Some(aim) = self.scene.light.beam_aim() {
            return self.beam_link(t, x, aim, bounces, rng, out);
        }
        let volume = t.flyer.volume;
        let q = self.light_point(rng)?;
        let inside = volume.field.bounds.contains(q);
        let first_only = self.scene.connections == super::Connections::First;
        let n_out = volume.field.n_out;
        let light = &self.scene.light;
        if inside {
            // a curved connection inside (after the way's reflections inside the surface), or
            // out of x's volume and into the light's: dA_q/dω_x is its spread
            // (bidirectional tracing's weights leave reflections off an outside to tracing)
            let mirrors = !either_end;
            let s = t
                .connector
                .sample_inside(x, q, (bounces, mirrors), first_only, rng);
            let (path, inverse_p) = self.tally(s, out)?;
            if either_end && !path.fits_either_way() {
                return None;
            }
            let leaving_q = -path.arrival().1;
            let n_q = t.flyer.n(q);
            let transmittance = self.path_transmittance(t, x, &path, rng);
            let intensity = light.intensity(leaving_q);
            Some(LightLink {
                direction: path.direction(),
                radiance: n_out * n_out * intensity * transmittance * path.fresnel()
                    / (n_q * n_q * path.spread())
                    * inverse_p,
                delay: t.path_delay(&path),
                inside: path.lengths(volume),
                outside: path.outside(),
                pdf: intensity,
                rays: Rays::Spreading,
            })
        } else {
            let bounces = self.exit_bounces(t, bounces, rng);
            let s = t
                .connector
                .sample_through(x, Aim::Point(q), &bounces, first_only, rng);
            let (e, inverse_p) = self.tally(s, out)?;
            let to_q = (q - e.surface).dot(e.outgoing);
            if self.scene.blocked(e.surface, e.outgoing, to_q) {
                return None;
            }
            let transmittance = self.exit_transmittance(t, &e, bounces.first, rng);
            // n_q = n_out: the camera's n_out² cancels it
            let intensity = light.intensity(-e.outgoing);
            // the path's optical length holds the straight stretch to the light
            let outside = n_out * (e.outside() + to_q);
            Some(LightLink {
                direction: e.direction,
                radiance: intensity * transmittance * e.transmission / e.jacobian * inverse_p,
                delay: t.exit_delay(&e, outside),
                inside: e.lengths(volume),
                outside: e.outside() + to_q,
                pdf: intensity,
                rays: Rays::Spreading,
            })
        }
    }

    /// The connection from a beam to `x` inside the volume: the path leaving `x` back along the
    /// beam (`aim`), after `bounces` reflections inside the surface of its part, out of the
    /// volume (refracted, and across the parts it meets) and straight to the beam's disc.
    /// From a collimated beam it is an orthographic camera's connection
    /// ([`ParticleTracer::camera_link`]) run the other way: the disc's rays reach `x` with the
    /// irradiance `T (1 − R) n_x² / (n_out² A dω_out/dω)` per unit power (`A` the disc's area,
    /// `dω_out/dω` the spread of the directions leaving `x` the connection solves for; the
    /// étendue `n_x² dA_x dω_x = n_out² dA dω_out`), so in basic radiance, times the camera's
    /// `n_out²`, it brings `T (1 − R) / (A dω_out/dω)`. A focused beam's rays outside the volume
    /// are the lines through its focus, those of a point light there of intensity
    /// [`Light::focus_intensity`] `I`: the path leaves along the line through the focus (which
    /// may lie behind the exit, inside the volume: the étendue holds along the lines' straight
    /// extension) and brings `I T (1 − R) / (dA⊥/dω)`, `dA⊥/dω` the tube's cross-section at the
    /// focus, as from a point light outside.
    fn beam_link(
        &self,
        t: &Tools,
        x: DVec3,
        aim: Aim,
        bounces: usize,
        rng: &mut Rng,
        out: &mut [C64],
    ) -> Option<LightLink> {
        let first_only = self.scene.connections == super::Connections::First;
        let bounces = self.exit_bounces(t, bounces, rng);
        let s = match aim {
            Aim::Point(_) | Aim::Focus { .. } => t
                .connector
                .sample_through(x, aim, &bounces, first_only, rng),
            _ => t.connector.sample_exit(x, aim, &bounces, first_only, rng),
        };
        let (e, inverse_p) = self.tally(s, out)?;
        self.link_from_disc(t, &e, || {
            let transmittance = self.exit_transmittance(t, &e, bounces.first, rng);
            transmittance * e.transmission / e.jacobian * inverse_p
        })
    }

    /// The link from a beam's disc of the path `e` that has left the volume back along the
    /// beam, if it meets the disc ([`Self::to_beam_disc`]): `carried()` is what the path
    /// carries per unit density of the beam there, asked for only then.
    fn link_from_disc(
        &self,
        t: &Tools,
        e: &Exit,
        carried: impl FnOnce() -> f64,
    ) -> Option<LightLink> {
        let ray = self.to_beam_disc(t, e.surface, e.outgoing)?;
        let volume = t.flyer.volume;
        let n_out = volume.field.n_out;
        // a path aimed at a focus holds the stretch to the disc in its optical path, one that
        // leaves along a direction ends where it leaves
        let delay = match ray.rays {
            Rays::Focused(_) => t.exit_delay(e, n_out * (e.outside() + ray.to_disc)),
            _ => t.exit_delay(e, n_out * e.outside()) + t.delay.outside(n_out * ray.to_disc),
        };
        Some(LightLink {
            direction: e.direction,
            radiance: ray.density * carried(),
            delay,
            inside: e.lengths(volume),
            outside: e.outside() + ray.to_disc,
            pdf: ray.density,
            rays: ray.rays,
        })
    }

    /// The connection from a beam to the lit point `y` of a surface (as
    /// [`Self::surface_light_link`]): straight back along the beam (`aim`) to its disc, past no
    /// other surface and through the volume only where it is index-matched, `T cos θ / A` from
    /// a collimated beam, `I T cos θ / r²` from a focused one `r` from its focus; or across the
    /// volume or off its outside (`way`), leaving it back along the beam, `T (1 − R) cos θ /
    /// (A dω_out/dω)` or `I T (1 − R) cos θ / (dA⊥/dω)` (both ends in `n_out`).
    #[allow(clippy::too_many_arguments)]
    fn surface_beam_link(
        &self,
        t: &Tools,
        y: DVec3,
        facing: DVec3,
        aim: Aim,
        way: Way,
        rng: &mut Rng,
        out: &mut [C64],
    ) -> Option<LightLink> {
        let volume = t.flyer.volume;
        let n_out = volume.field.n_out;
        match way {
            Way::Across | Way::Mirror => {
                let (e, carried) = self.across(t, y, aim, way, rng, out)?;
                let cos = e.direction.dot(facing);
                if cos <= 0.0 {
                    return None;
                }
                self.link_from_disc(t, &e, || cos * carried)
            }
            Way::Bounces(0) => {
                let back = aim.toward(y);
                let cos = back.dot(facing);
                if cos <= 0.0 {
                    return None;
                }
                let ray = self.to_beam_disc(t, y, back)?;
                // |y − f|² from a focus, 1 for parallel rays
                let spread = ray.rays.spread(ray.to_disc);
                if spread <= 0.0 {
                    return None;
                }
                let (transmittance, inside) = self.past_volume(t, y, back, ray.to_disc, rng)?;
                Some(LightLink {
                    direction: back,
                    radiance: ray.density * cos * transmittance / spread,
                    delay: t.delay.outside(n_out * ray.to_disc),
                    inside,
                    outside: ray.to_disc - inside.total(),
                    pdf: ray.density,
                    rays: ray.rays,
                })
            }
            Way::Bounces(_) => None,
        }
    }

    /// The beam's ray through `p` (outside the volume) that arrives travelling along `−back`, if
    /// the beam lights `p` along it ([`Light::beam_ray`]): from a point of its disc outside the
    /// volume, past no surface on the way.
    fn to_beam_disc(&self, t: &Tools, p: DVec3, back: DVec3) -> Option<super::scene::BeamRay> {
        let ray = self.scene.light.beam_ray(p, back)?;
        let start = p + back * ray.to_disc;
        let clear = !t.flyer.volume.field.bounds.contains(start)
            && !self.scene.blocked(p, back, ray.to_disc);
        clear.then_some(ray)
    }

    /// Free flights and scattering of the camera path inside the volume.
    #[allow(clippy::too_many_arguments)]
    fn camera_inside(
        &self,
        t: &Tools,
        mut ray: Ray,
        w: &mut Walk,
        pixel: &Pixel,
        rng: &mut Rng,
        out: &mut [C64],
    ) -> Option<Leg> {
        let mut reflections = Reflections::default();
        loop {
            let (stop, travelled) = t.next_event(ray, rng);
            w.steps += travelled.steps;
            w.opl += travelled.opl;
            match stop {
                Stop::Collision(hit) => {
                    w.events += 1;
                    w.beta *= t.flyer.volume.albedo_at(hit.x);
                    reflections = Reflections::default();
                    let u = hit.v.normalize();
                    self.light_to_event(t, hit.x, u, w, pixel, rng, out);
                    if !w.roulette(rng) || w.events >= super::particle::MAX_EVENTS {
                        return None;
                    }
                    ray = t.scatter(hit.x, u, rng);
                }
                Stop::Boundary(end) => match Leg::leave(t, end, rng) {
                    Leg::Inside(reflected) if reflections.another() => ray = reflected,
                    // given up
                    Leg::Inside(_) => return None,
                    out => return Some(out),
                },
                Stop::Stuck => return None,
            }
        }
    }
}
