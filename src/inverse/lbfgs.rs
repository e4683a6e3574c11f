//! The one L-BFGS driver (argmin's L-BFGS with a Moré–Thuente line search) for smooth,
//! deterministic objectives, optionally inside a box.
//!
//! Bounds are honoured by projection: the objective is evaluated at the projection `P(x)` of every
//! point the line search proposes, plus `κ/2 |x − P(x)|²`, so the wrapped function is continuous
//! and its minimiser over all of space is the constrained one. The driver returns the best point it
//! **evaluated** (a feasible point with its loss and gradient), never a point it did not evaluate,
//! and says why it stopped: the projected gradient is below tolerance (a KKT point), the cost no
//! longer changes, the iteration limit, or the line search gave up. Observers see every evaluation.
//! Proposals beyond a bound often project to a point already evaluated (an optimum in a corner of
//! the box draws the line search there again and again): the recent evaluations are kept and
//! reused, so each feasible point costs the objective once.

use argmin::core::{
    CostFunction, Error as ArgminError, Executor, Gradient, State, TerminationReason,
};
use argmin::solver::linesearch::MoreThuenteLineSearch;
use argmin::solver::quasinewton::LBFGS;
use serde::{Deserialize, Serialize};
use std::sync::Mutex;

/// A smooth objective: value and gradient at `x` together.
pub trait Objective: Sync {
    fn eval(&self, x: &[f64]) -> crate::Result<(f64, Vec<f64>)>;
}

/// A box `lower ≤ x ≤ upper`.
#[derive(Clone, Debug, PartialEq)]
pub struct Bounds {
    pub lower: Vec<f64>,
    pub upper: Vec<f64>,
}

impl Bounds {
    fn project(&self, x: &[f64]) -> Vec<f64> {
        x.iter()
            .zip(self.lower.iter().zip(&self.upper))
            .map(|(x, (lo, hi))| {
                if x.is_finite() {
                    x.clamp(*lo, *hi)
                } else {
                    0.5 * (lo + hi)
                }
            })
            .collect()
    }

    /// Whether coordinate `i` of `x` sits on its bound (within a relative `1e-9` of the width).
    pub fn at_bound(&self, x: &[f64], i: usize) -> bool {
        let eps = 1e-9 * (self.upper[i] - self.lower[i]).abs().max(1e-300);
        x[i] <= self.lower[i] + eps || x[i] >= self.upper[i] - eps
    }
}

/// Settings of one minimisation.
#[derive(Clone, Debug)]
pub struct Settings {
    pub max_iters: usize,
    /// Converged when the projected gradient's norm is below this.
    pub grad_tol: f64,
    /// Converged when an iteration changes the cost by less than this.
    pub cost_tol: f64,
    pub bounds: Option<Bounds>,
}

/// Why a minimisation stopped.
#[derive(Clone, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Stop {
    /// The projected gradient is below tolerance.
    GradientTolerance,
    /// An iteration changed the cost by less than the tolerance.
    CostChange,
    IterationLimit,
    /// The line search found no acceptable step (the message says why).
    LineSearch(String),
}

impl Stop {
    pub fn converged(&self) -> bool {
        matches!(self, Stop::GradientTolerance | Stop::CostChange)
    }

    /// A short phrase for logs and messages.
    pub fn describe(&self) -> String {
        match self {
            Stop::GradientTolerance => "gradient below tolerance".into(),
            Stop::CostChange => "cost no longer changes".into(),
            Stop::IterationLimit => "iteration limit reached".into(),
            Stop::LineSearch(m) => format!("line search gave up ({m})"),
        }
    }
}

/// One evaluation, as observers see it.
#[derive(Clone, Debug)]
pub struct Evaluation {
    pub index: usize,
    /// The feasible point evaluated.
    pub x: Vec<f64>,
    pub loss: f64,
    /// Norm of the projected gradient at `x`.
    pub grad_norm: f64,
}

/// The best evaluated point and how the minimisation ended.
#[derive(Clone, Debug)]
pub struct Outcome {
    pub x: Vec<f64>,
    pub loss: f64,
    /// Projected gradient at `x` (components pushing out of the box at a bound are zero).
    pub grad: Vec<f64>,
    pub grad_norm: f64,
    pub iterations: usize,
    pub evaluations: usize,
    pub stop: Stop,
    /// Coordinates of `x` that sit on a bound.
    pub at_bound: Vec<bool>,
}

/// Minimise `objective` from `x0`; `observe` sees every evaluation.
pub fn minimise(
    objective: &dyn Objective,
    x0: &[f64],
    settings: &Settings,
    observe: &(dyn Fn(&Evaluation) + Sync),
) -> crate::Result<Outcome> {
    if x0.iter().any(|x| !x.is_finite()) {
        return Err(format!("the starting point {x0:?} is not finite").into());
    }
    let wrapped = Wrapped {
        objective,
        bounds: settings.bounds.as_ref(),
        kappa: settings.bounds.as_ref().map_or(0.0, |b| {
            let w = b
                .lower
                .iter()
                .zip(&b.upper)
                .map(|(l, u)| u - l)
                .fold(f64::INFINITY, f64::min);
            10.0 / w.max(1e-12)
        }),
        observe,
        state: Mutex::new(Record::default()),
    };
    let start = wrapped.project(x0);
    let line = MoreThuenteLineSearch::new()
        .with_bounds(1e-12, 4.0)
        .map_err(|e| crate::Error::input(e.to_string()))?;
    let solver = LBFGS::new(line, 7)
        .with_tolerance_grad(settings.grad_tol)
        .map_err(|e| crate::Error::input(e.to_string()))?
        .with_tolerance_cost(settings.cost_tol)
        .map_err(|e| crate::Error::input(e.to_string()))?;
    let result = Executor::new(&wrapped, solver)
        .configure(|s| s.param(start).max_iters(settings.max_iters as u64))
        .run();
    let (iterations, reason) = match &result {
        Ok(r) => (
            r.state().get_iter() as usize,
            r.state().get_termination_reason().cloned(),
        ),
        Err(e) => (0, Some(TerminationReason::SolverExit(e.to_string()))),
    };
    drop(result);
    let record = wrapped.state.into_inner().unwrap_or_default();
    if let Some(e) = record.error {
        return Err(e);
    }
    let best = record
        .best
        .ok_or_else(|| "no point was evaluated".to_string())?;
    let stop = if best.grad_norm < settings.grad_tol {
        Stop::GradientTolerance
    } else {
        match reason {
            Some(TerminationReason::SolverConverged) => Stop::CostChange,
            Some(TerminationReason::MaxItersReached) | None => Stop::IterationLimit,
            Some(TerminationReason::SolverExit(m)) => Stop::LineSearch(m),
            Some(other) => Stop::LineSearch(other.text().to_string()),
        }
    };
    let at_bound = (0..best.x.len())
        .map(|i| {
            settings
                .bounds
                .as_ref()
                .is_some_and(|b| b.at_bound(&best.x, i))
        })
        .collect();
    Ok(Outcome {
        x: best.x,
        loss: best.loss,
        grad: best.grad,
        grad_norm: best.grad_norm,
        iterations,
        evaluations: record.evaluations,
        stop,
        at_bound,
    })
}

/// Feasible evaluations kept for reuse (besides the best).
const RECENT: usize = 16;

#[derive(Clone, Debug)]
struct Best {
    x: Vec<f64>,
    loss: f64,
    /// The projected gradient, and the objective's own.
    grad: Vec<f64>,
    raw: Vec<f64>,
    grad_norm: f64,
}

#[derive(Default)]
struct Record {
    evaluations: usize,
    best: Option<Best>,
    /// The last point asked for, with the wrapped cost and gradient (argmin asks for the cost and
    /// the gradient of one point separately).
    last: Option<(Vec<f64>, f64, Vec<f64>)>,
    /// The latest feasible points evaluated, with the objective's loss and gradient there.
    recent: std::collections::VecDeque<(Vec<f64>, f64, Vec<f64>)>,
    /// An error of the objective (argmin would otherwise report it as a line-search failure).
    error: Option<crate::Error>,
}

struct Wrapped<'a> {
    objective: &'a dyn Objective,
    bounds: Option<&'a Bounds>,
    kappa: f64,
    observe: &'a (dyn Fn(&Evaluation) + Sync),
    state: Mutex<Record>,
}

impl Wrapped<'_> {
    fn project(&self, x: &[f64]) -> Vec<f64> {
        self.bounds.map_or_else(|| x.to_vec(), |b| b.project(x))
    }

    /// Projected gradient: at a bound, a component that would push outwards is zero.
    fn projected(&self, p: &[f64], g: &[f64]) -> Vec<f64> {
        let Some(b) = self.bounds else {
            return g.to_vec();
        };
        g.iter()
            .enumerate()
            .map(|(i, &gi)| {
                let eps = 1e-9 * (b.upper[i] - b.lower[i]).abs().max(1e-300);
                let at_lo = p[i] <= b.lower[i] + eps && gi > 0.0;
                let at_hi = p[i] >= b.upper[i] - eps && gi < 0.0;
                if at_lo || at_hi { 0.0 } else { gi }
            })
            .collect()
    }

    fn eval(&self, x: &[f64]) -> Result<(f64, Vec<f64>), ArgminError> {
        let mut st = self
            .state
            .lock()
            .map_err(|_| ArgminError::msg("objective poisoned"))?;
        if let Some((lx, l, g)) = &st.last
            && lx.as_slice() == x
        {
            return Ok((*l, g.clone()));
        }
        let p = self.project(x);
        let best = st.best.as_ref().filter(|b| b.x == p);
        let seen = best.map(|b| (b.loss, b.raw.clone())).or_else(|| {
            let recent = st.recent.iter().find(|(q, ..)| *q == p);
            recent.map(|(_, loss, grad)| (*loss, grad.clone()))
        });
        let (loss, grad) = match seen {
            Some(known) => known,
            None => {
                let (loss, grad) = match self.objective.eval(&p) {
                    Ok(r) => r,
                    Err(e) => {
                        let message = ArgminError::msg(e.to_string());
                        st.error.get_or_insert(e);
                        return Err(message);
                    }
                };
                let pg = self.projected(&p, &grad);
                let grad_norm = pg.iter().map(|g| g * g).sum::<f64>().sqrt();
                let index = st.evaluations;
                st.evaluations += 1;
                (self.observe)(&Evaluation {
                    index,
                    x: p.clone(),
                    loss,
                    grad_norm,
                });
                let finite = loss.is_finite() && grad.iter().all(|g| g.is_finite());
                if finite && st.best.as_ref().is_none_or(|b| loss < b.loss) {
                    st.best = Some(Best {
                        x: p.clone(),
                        loss,
                        grad: pg,
                        raw: grad.clone(),
                        grad_norm,
                    });
                }
                if st.recent.len() == RECENT {
                    st.recent.pop_front();
                }
                st.recent.push_back((p.clone(), loss, grad.clone()));
                (loss, grad)
            }
        };
        let finite = loss.is_finite() && grad.iter().all(|g| g.is_finite());
        // outside the box: f(P(x)) + κ/2 |x − P(x)|², whose gradient is ∇f at P(x) with the clamped
        // components replaced by the restoring force κ (x − P(x))
        let out: f64 = x.iter().zip(&p).map(|(a, b)| (a - b) * (a - b)).sum();
        let (cost, g) = if finite {
            let g: Vec<f64> = x
                .iter()
                .zip(&p)
                .zip(&grad)
                .map(|((xi, pi), gi)| {
                    if xi != pi {
                        self.kappa * (xi - pi)
                    } else {
                        *gi
                    }
                })
                .collect();
            (loss + 0.5 * self.kappa * out, g)
        } else {
            // a point the data cannot explain still ranks worse than any finite one
            (f64::MAX / 4.0, vec![0.0; x.len()])
        };
        st.last = Some((x.to_vec(), cost, g.clone()));
        Ok((cost, g))
    }
}

impl CostFunction for &Wrapped<'_> {
    type Param = Vec<f64>;
    type Output = f64;
    fn cost(&self, x: &Vec<f64>) -> Result<f64, ArgminError> {
        self.eval(x).map(|r| r.0)
    }
}

impl Gradient for &Wrapped<'_> {
    type Param = Vec<f64>;
    type Gradient = Vec<f64>;
    fn gradient(&self, x: &Vec<f64>) -> Result<Vec<f64>, ArgminError> {
        self.eval(x).map(|r| r.1)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Rosenbrock in a box whose optimum is cut off: the driver must stop at the constrained
    /// minimiser on the bound, report the bound, and return a point it evaluated.
    struct Rosenbrock;
    impl Objective for Rosenbrock {
        fn eval(&self, x: &[f64]) -> crate::Result<(f64, Vec<f64>)> {
            let (a, b) = (x[0], x[1]);
            let f = (1.0 - a).powi(2) + 100.0 * (b - a * a).powi(2);
            let g = vec![
                -2.0 * (1.0 - a) - 400.0 * a * (b - a * a),
                200.0 * (b - a * a),
            ];
            Ok((f, g))
        }
    }

    #[test]
    fn unconstrained_rosenbrock_converges() {
        let s = Settings {
            max_iters: 200,
            grad_tol: 1e-8,
            cost_tol: 0.0,
            bounds: None,
        };
        let o = minimise(&Rosenbrock, &[-1.2, 1.0], &s, &|_| {}).unwrap();
        assert!(
            (o.x[0] - 1.0).abs() < 1e-6 && (o.x[1] - 1.0).abs() < 1e-6,
            "{o:?}"
        );
        assert_eq!(o.stop, Stop::GradientTolerance);
        assert!(o.evaluations > o.iterations);
    }

    #[test]
    fn box_constrained_minimum_on_the_bound() {
        let seen = Mutex::new(Vec::new());
        let s = Settings {
            max_iters: 200,
            grad_tol: 1e-8,
            cost_tol: 0.0,
            bounds: Some(Bounds {
                lower: vec![-2.0, -2.0],
                upper: vec![0.5, 2.0],
            }),
        };
        let o = minimise(&Rosenbrock, &[-1.2, 1.0], &s, &|e| {
            seen.lock().unwrap().push((e.x.clone(), e.loss))
        })
        .unwrap();
        // constrained optimum: a = 0.5, b = 0.25
        assert!(
            (o.x[0] - 0.5).abs() < 1e-9 && (o.x[1] - 0.25).abs() < 1e-5,
            "{o:?}"
        );
        assert_eq!(o.at_bound, vec![true, false]);
        assert!(o.stop.converged(), "{:?}", o.stop);
        // the returned point was evaluated, with the loss reported, and every evaluated point is
        // feasible
        let seen = seen.into_inner().unwrap();
        assert!(seen.iter().any(|(x, l)| *x == o.x && *l == o.loss));
        assert!(seen.iter().all(|(x, _)| x[0] <= 0.5 && x[0] >= -2.0));
    }

    /// `f = x + y` in the unit box: the optimum is the corner (0, 0), where the line search keeps
    /// proposing points beyond both bounds. Each feasible point is evaluated once.
    #[test]
    fn a_corner_optimum_is_evaluated_once() {
        struct Plane(Mutex<Vec<Vec<f64>>>);
        impl Objective for Plane {
            fn eval(&self, x: &[f64]) -> crate::Result<(f64, Vec<f64>)> {
                self.0.lock().unwrap().push(x.to_vec());
                Ok((x[0] + x[1], vec![1.0, 1.0]))
            }
        }
        let plane = Plane(Mutex::new(Vec::new()));
        let s = Settings {
            max_iters: 30,
            grad_tol: 1e-8,
            cost_tol: 0.0,
            bounds: Some(Bounds {
                lower: vec![0.0, 0.0],
                upper: vec![1.0, 1.0],
            }),
        };
        let o = minimise(&plane, &[0.7, 0.4], &s, &|_| {}).unwrap();
        assert_eq!(o.x, vec![0.0, 0.0]);
        assert_eq!(o.stop, Stop::GradientTolerance);
        let asked = plane.0.into_inner().unwrap();
        assert_eq!(o.evaluations, asked.len());
        let corner = asked.iter().filter(|x| **x == [0.0, 0.0]).count();
        assert_eq!(corner, 1, "{asked:?}");
    }

    #[test]
    fn iteration_limit_is_reported() {
        let s = Settings {
            max_iters: 3,
            grad_tol: 1e-12,
            cost_tol: 0.0,
            bounds: None,
        };
        let o = minimise(&Rosenbrock, &[-1.2, 1.0], &s, &|_| {}).unwrap();
        assert_eq!(o.stop, Stop::IterationLimit);
        assert!(!o.stop.converged());
    }
}
