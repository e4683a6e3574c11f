//! Rendered sensor powers (targets' and probes' fluences too) as a differentiable function of the medium's
//! and the index field's parameters, for the burn bridge ([`super::bridge`]) and any other
//! reverse-mode user.
//!
//! [`RenderOp`] maps `θ` (values of [`Param`]s of the refractive renderer's homogeneous medium,
//! then of the index field's parameters) to what every sensor receives, estimated by particle
//! tracing; its pullback is the transposed Jacobian the same photons estimate by their path-space
//! scores and forward sensitivities (`render.derivatives`). Each evaluation draws fresh photons
//! (the seed advances): unbiased values and gradients of the expected outputs, as stochastic
//! optimisers (Adam) expect. Held ([`RenderOp::hold`]), every evaluation draws the same photons:
//! a smooth deterministic estimate with its exact gradient, as L-BFGS expects.

use super::bridge::{Differentiable, Pullback};
use super::{Param, medium_at};
use crate::mc::{Plan, StopFlag, estimate_until};
use crate::medium::{Geometry, Medium};
use crate::rrte::{
    Bulk, Derivative, FieldDerivative, MediumDerivative, ParticleTracer, RenderScene, Tracing,
};
use std::sync::Arc;
use std::sync::atomic::{AtomicU64, Ordering};

/// `θ ↦ (power of sensor 0, power of sensor 1, …, fluence of probe 0, …)` of a render (its
/// [`RenderScene::objectives`]), with its score pullback.
pub struct RenderOp {
    pub scene: RenderScene,
    /// The medium's parameters, each of the one volume or of one of several.
    pub params: Vec<MediumDerivative>,
    /// Index-field parameters, after `params` in `θ` (none from [`Self::new`]).
    pub field: Vec<FieldDerivative>,
    pub samples: u64,
    pub chunk: u64,
    pub seed: u64,
    /// Stops every forward of this operation once set (none from [`Self::new`]).
    pub stop: StopFlag,
    /// Whether the photons are held ([`Self::hold`]).
    held: bool,
    evaluations: AtomicU64,
}

/// The powers of one evaluation, their standard errors, `∂ power_i/∂θ_p` (rows: the scene's
/// objectives) and its standard errors.
#[derive(Clone, Debug)]
pub struct RenderEvaluation {
    pub power: Vec<f64>,
    pub stderr: Vec<f64>,
    pub jacobian: Vec<Vec<f64>>,
    pub jacobian_stderr: Vec<Vec<f64>>,
}

impl Pullback for RenderEvaluation {
    fn pullback(&self, dy: &[f64]) -> Vec<f64> {
        let np = self.jacobian.first().map_or(0, Vec::len);
        (0..np)
            .map(|p| {
                self.jacobian
                    .iter()
                    .zip(dy)
                    .map(|(row, d)| row[p] * d)
                    .sum()
            })
            .collect()
    }
}

impl RenderOp {
    /// The operation on `scene` (particle tracing, a homogeneous medium of one volume that has
    /// every parameter of `params`, at least one sensor), `samples` photons per evaluation.
    pub fn new(
        scene: RenderScene,
        params: Vec<Param>,
        sizes: (u64, u64, u64),
    ) -> crate::Result<Self> {
        if !scene.volume.parts.is_empty() {
            return Err(
                "a scene of several volumes: name each medium parameter's volume (RenderOp::from_scene, volume[i].sigma_s)".into(),
            );
        }
        let params = params.into_iter().map(MediumDerivative::of_one).collect();
        Self::of_medium(scene, params, sizes)
    }

    /// [`Self::new`] with parameters of the one volume's or several volumes' media.
    fn of_medium(
        scene: RenderScene,
        params: Vec<MediumDerivative>,
        (samples, chunk, seed): (u64, u64, u64),
    ) -> crate::Result<Self> {
        if scene.tracing != Tracing::FromLight {
            return Err("a render's derivatives come from particle tracing".into());
        }
        if scene.volume.density.is_some() {
            return Err("a render's derivatives need a homogeneous medium (no density)".into());
        }
        if scene.objectives().is_empty() {
            return Err(
                "a render operation's outputs are its sensors' powers and probes' fluences: give a sensor".into(),
            );
        }
        if params.len() > crate::rrte::MAX_DERIVATIVES {
            return Err(format!(
                "{} parameters: a render differentiates at most {}",
                params.len(),
                crate::rrte::MAX_DERIVATIVES
            )
            .into());
        }
        if samples == 0 {
            return Err("a render operation needs at least one photon".into());
        }
        Ok(RenderOp {
            scene,
            params,
            field: Vec::new(),
            samples,
            chunk,
            seed,
            stop: StopFlag::default(),
            held: false,
            evaluations: AtomicU64::new(0),
        })
    }

    /// The operation on a configured scene, differentiated by the parameters its
    /// `render.derivatives` names: `θ` holds the medium's first, then the index field's, each in
    /// the config's order.
    pub fn from_scene(scene: RenderScene, sizes: (u64, u64, u64)) -> crate::Result<Self> {
        let params = scene
            .derivatives
            .iter()
            .filter_map(Derivative::medium)
            .collect();
        let field: Vec<FieldDerivative> = scene
            .derivatives
            .iter()
            .filter_map(|d| match d {
                Derivative::Field(f) => Some(f.clone()),
                Derivative::Medium(_) => None,
            })
            .collect();
        if !field.is_empty()
            && let Some(s) = scene
                .sensors
                .iter()
                .find(|s| !s.follows_light_continuously())
        {
            return Err(format!(
                "sensor {:?}: a render's derivatives with respect to the index field are of targets, spots and tent-filtered screens, whose response follows the light continuously",
                s.name
            )
            .into());
        }
        let mut op = Self::of_medium(scene, params, sizes)?;
        if op.params.len() + field.len() > crate::rrte::MAX_DERIVATIVES {
            return Err(format!(
                "{} parameters: a render differentiates at most {}",
                op.params.len() + field.len(),
                crate::rrte::MAX_DERIVATIVES
            )
            .into());
        }
        op.field = field;
        Ok(op)
    }

    /// Hold the photons: every evaluation draws the same random numbers (the seed does not
    /// advance) and every scored choice with probability ½, so the estimate is a deterministic
    /// function of the index field's parameters whose Jacobian is its exact derivative (a
    /// sample-average approximation, for L-BFGS). Refused with medium parameters: their
    /// derivatives are path scores, which a held sample's estimate does not follow.
    pub fn hold(&mut self) -> crate::Result<()> {
        if let Some(p) = self.params.first() {
            return Err(format!(
                "{}: held photons follow their paths as the index field moves; a medium parameter is differentiated by its paths' scores instead, which a held sample does not follow",
                p.name()
            )
            .into());
        }
        self.held = true;
        Ok(())
    }

    /// The parameters' values in the scene (`θ` where it was configured).
    pub fn values(&self) -> Vec<f64> {
        let v = &self.scene.volume;
        let mut theta: Vec<f64> = self
            .params
            .iter()
            .map(|p| {
                let m = self.bulk(p.volume);
                p.param
                    .value_in(m.sigma_s, m.sigma_a, &m.scattering)
                    .unwrap_or(0.0)
            })
            .collect();
        for f in &self.field {
            let stored = f.stored(&v.field).unwrap_or(0.0);
            theta.push(if f.scale != 0.0 {
                stored / f.scale
            } else {
                0.0
            });
        }
        theta
    }

    /// The scene at `θ`, to render without derivatives (a design's check).
    pub fn scene_without_derivatives(&self, theta: &[f64]) -> crate::Result<RenderScene> {
        let (mut scene, _) = self.scene_at(theta)?;
        scene.derivatives.clear();
        Ok(scene)
    }

    /// How many evaluations have been made (each uses the next seed).
    pub fn evaluations(&self) -> u64 {
        self.evaluations.load(Ordering::Relaxed)
    }

    /// The bulk medium of volume `k` of several, or of the one volume (`None`).
    fn bulk(&self, k: Option<usize>) -> Bulk {
        let v = &self.scene.volume;
        match k {
            Some(k) => v.parts[k].clone(),
            None => Bulk {
                sigma_s: v.sigma_s,
                sigma_a: v.sigma_a,
                scattering: v.scattering.clone(),
            },
        }
    }

    /// The scene with its media at `θ`, and per parameter the factor turning the scores'
    /// derivative into `∂/∂θ` (unnormalised table nodes and shares, as [`medium_at`]).
    fn scene_at(&self, theta: &[f64]) -> crate::Result<(RenderScene, Vec<f64>)> {
        let m_count = self.params.len();
        if theta.len() != m_count + self.field.len() {
            return Err(format!(
                "{} parameter values for {} parameters",
                theta.len(),
                m_count + self.field.len()
            )
            .into());
        }
        let mut scene = self.scene.clone();
        let mut factor = vec![1.0; m_count];
        // each volume's medium at its parameters' values
        let mut volumes: Vec<Option<usize>> = self.params.iter().map(|p| p.volume).collect();
        volumes.sort();
        volumes.dedup();
        for k in volumes {
            let mine: Vec<usize> = (0..m_count)
                .filter(|&i| self.params[i].volume == k)
                .collect();
            let bulk = self.bulk(k);
            let base = Medium {
                // only the coefficients and particles are read
                geometry: Geometry::boxed([1.0; 3]),
                sigma_s: bulk.sigma_s,
                sigma_a: bulk.sigma_a,
                scattering: bulk.scattering,
            };
            let params: Vec<Param> = mine.iter().map(|&i| self.params[i].param).collect();
            let values: Vec<f64> = mine.iter().map(|&i| theta[i]).collect();
            let (m, f) = medium_at(&base, &params, &values).map_err(|e| match k {
                Some(k) => format!("volume[{k}]: {e}").into(),
                None => e,
            })?;
            for (&i, f) in mine.iter().zip(f) {
                factor[i] = f;
            }
            let (sigma_s, sigma_a, scattering) = match k {
                Some(k) => {
                    let b = &mut scene.volume.parts[k];
                    (&mut b.sigma_s, &mut b.sigma_a, &mut b.scattering)
                }
                None => {
                    let v = &mut scene.volume;
                    (&mut v.sigma_s, &mut v.sigma_a, &mut v.scattering)
                }
            };
            (*sigma_s, *sigma_a, *scattering) = (m.sigma_s, m.sigma_a, m.scattering);
        }
        for (f, &value) in self.field.iter().zip(&theta[m_count..]) {
            if !value.is_finite() {
                return Err(format!("{} = {value}: not a finite number", f.name).into());
            }
            f.change(&mut scene.volume.field, |x| *x = value * f.scale);
        }
        factor.extend(std::iter::repeat_n(1.0, self.field.len()));
        scene.derivatives = self
            .params
            .iter()
            .map(|&m| Derivative::Medium(m))
            .chain(self.field.iter().cloned().map(Derivative::Field))
            .collect();
        Ok((scene, factor))
    }

    /// Render at `θ`: the powers, their errors and the Jacobian.
    pub fn evaluate(&self, theta: &[f64]) -> crate::Result<RenderEvaluation> {
        let (scene, factor) = self.scene_at(theta)?;
        let k = self.evaluations.fetch_add(1, Ordering::Relaxed);
        let seed = if self.held {
            self.seed
        } else {
            self.seed.wrapping_add(k)
        };
        let plan = Plan::new(seed, self.samples, self.chunk);
        let mut est = ParticleTracer::new(&scene);
        est.even_draws = self.held;
        let e = estimate_until(&est, &plan, self.stop.get())?;
        let outputs = scene.objectives().len();
        // the derivative outputs scaled by each parameter's factor (errors by its size)
        let per_parameter = |value: &dyn Fn(usize, f64) -> f64| -> Vec<Vec<f64>> {
            (0..outputs)
                .map(|i| {
                    factor
                        .iter()
                        .enumerate()
                        .map(|(p, &f)| value(est.objective_derivative(i, p), f))
                        .collect()
                })
                .collect()
        };
        let out = RenderEvaluation {
            power: (0..outputs).map(|i| e.mean[est.objective(i)].re).collect(),
            stderr: (0..outputs).map(|i| e.stderr[est.objective(i)]).collect(),
            jacobian: per_parameter(&|k, f| e.mean[k].re * f),
            jacobian_stderr: per_parameter(&|k, f| e.stderr[k] * f.abs()),
        };
        if out
            .power
            .iter()
            .chain(out.jacobian.iter().flatten())
            .any(|v| !v.is_finite())
        {
            return Err("render: a power or derivative is not finite".into());
        }
        Ok(out)
    }
}

impl Differentiable for RenderOp {
    fn forward(&self, theta: &[f64]) -> crate::Result<(Vec<f64>, Arc<dyn Pullback>)> {
        let e = self.evaluate(theta)?;
        Ok((e.power.clone(), Arc::new(e)))
    }
}
