//! The one Adam driver (Kingma & Ba's Adam over one vector of variables, in `f64`) for losses
//! written in burn tensors, the plateau rule that says whether a run of fixed length converged,
//! and the checkpoints that let a killed run continue to the same bits.
//!
//! The update is burn's (its defaults β₁ = 0.9, β₂ = 0.999, ε = 1e-5, ε scaled by the second
//! moment's bias correction), kept here in `f64` so that its state — the variables and both
//! moments — can be saved and restored exactly.

use super::journal::{Journal, Numbers, key};
use crate::diff::bridge::{device, tensor, values};
use burn::tensor::Tensor;

const BETA_1: f64 = 0.9;
const BETA_2: f64 = 0.999;
const EPSILON: f64 = 1e-5;

/// One iteration as the observer sees it: the norm of the loss gradient at the variables before
/// the step, and what the loss closure returned for observation.
pub struct Iterate<O> {
    pub iteration: usize,
    pub grad_norm: f64,
    pub observed: O,
}

/// What a run returns: the variables after the last step, and their mean over the iterations from
/// `average_from` on (the iterates before each step; empty when no iteration is averaged).
pub struct Minimised {
    pub last: Vec<f64>,
    pub average: Vec<f64>,
}

/// Adam's state after `steps` steps: the variables, both moments and the running average.
#[derive(Clone, Debug, PartialEq)]
struct State {
    steps: usize,
    x: Vec<f64>,
    m: Vec<f64>,
    v: Vec<f64>,
    average: Vec<f64>,
}

impl State {
    fn new(x0: &[f64], averaged: bool) -> Self {
        let n = x0.len();
        State {
            steps: 0,
            x: x0.to_vec(),
            m: vec![0.0; n],
            v: vec![0.0; n],
            average: vec![0.0; if averaged { n } else { 0 }],
        }
    }

    /// One step of size `lr` along the moments updated with gradient `g`.
    fn step(&mut self, lr: f64, g: &[f64]) {
        self.steps += 1;
        let t = self.steps as i32;
        let correction_2 = (1.0 - BETA_2.powi(t)).sqrt();
        let factor = lr * correction_2 / (1.0 - BETA_1.powi(t));
        let eps = EPSILON * correction_2;
        for (((x, m), v), g) in self.x.iter_mut().zip(&mut self.m).zip(&mut self.v).zip(g) {
            *m = BETA_1 * *m + (1.0 - BETA_1) * g;
            *v = BETA_2 * *v + (1.0 - BETA_2) * g * g;
            *x -= factor * *m / (v.sqrt() + eps);
        }
    }

    /// Little endian: `steps`, the lengths of `x` and `average`, then `x`, `m`, `v`, `average`.
    fn to_bytes(&self) -> Vec<u8> {
        let floats = self
            .x
            .iter()
            .chain(&self.m)
            .chain(&self.v)
            .chain(&self.average);
        let mut b = Vec::with_capacity(8 * (3 + 3 * self.x.len() + self.average.len()));
        for w in [self.steps, self.x.len(), self.average.len()] {
            b.extend_from_slice(&(w as u64).to_le_bytes());
        }
        floats.for_each(|v| b.extend_from_slice(&v.to_le_bytes()));
        b
    }

    fn from_bytes(b: &[u8]) -> Option<Self> {
        let words: Vec<u64> = b
            .chunks(8)
            .map(|c| Some(u64::from_le_bytes(c.try_into().ok()?)))
            .collect::<Option<_>>()?;
        let (&[steps, n, na], rest) = words.split_first_chunk::<3>()?;
        let (n, na) = (n as usize, na as usize);
        if rest.len() != 3 * n + na {
            return None;
        }
        let f = |r: &[u64]| r.iter().map(|w| f64::from_bits(*w)).collect::<Vec<_>>();
        Some(State {
            steps: steps as usize,
            x: f(&rest[..n]),
            m: f(&rest[n..2 * n]),
            v: f(&rest[2 * n..3 * n]),
            average: f(&rest[3 * n..]),
        })
    }
}

/// Minimise from `x0` for `iterations` Adam steps of size `learning_rate(iteration)`. `loss(it, x)`
/// builds the loss at `x` in burn tensors and returns it with what the observer should see;
/// `observe` sees every iteration and may stop the run with an error (e.g. a non-finite loss).
/// Each iteration is recorded in `journal` (its observation; Adam's state when a save is due), so
/// a resumed run replays the observations and continues from the saved state: `loss` must depend
/// on the iteration and the variables only.
pub fn minimise<O: Numbers>(
    x0: &[f64],
    iterations: usize,
    learning_rate: &dyn Fn(usize) -> f64,
    average_from: usize,
    journal: &Journal,
    loss: &mut dyn FnMut(usize, Tensor<1>) -> crate::Result<(Tensor<1>, O)>,
    observe: &mut dyn FnMut(Iterate<O>) -> crate::Result<()>,
) -> crate::Result<Minimised> {
    let n = x0.len();
    let averaged = iterations.saturating_sub(average_from);
    let run = f64::from_bits(key(x0));
    let mut live: Option<State> = None;
    for iteration in 0..iterations {
        let inputs = [run, iteration as f64];
        let state = match &mut live {
            Some(state) => state,
            None => {
                if let Some(v) = journal.replay(&inputs)? {
                    let (grad_norm, observed) =
                        <(f64, O)>::from_numbers(&v).ok_or_else(mismatch)?;
                    observe(Iterate {
                        iteration,
                        grad_norm,
                        observed,
                    })?;
                    continue;
                }
                let state = match journal.take_snapshot() {
                    Some(bytes) => State::from_bytes(&bytes)
                        .filter(|s| {
                            (s.steps, s.x.len(), !s.average.is_empty())
                                == (iteration, n, averaged > 0)
                        })
                        .ok_or_else(mismatch)?,
                    None if iteration == 0 => State::new(x0, averaged > 0),
                    None => return Err(mismatch()),
                };
                live.insert(state)
            }
        };
        let x = tensor(&state.x, &device()).require_grad();
        let (total, observed) = loss(iteration, x.clone())?;
        let grads = total.backward();
        let g = x
            .grad(&grads)
            .map(|g| values(&g))
            .unwrap_or_else(|| vec![0.0; n]);
        let grad_norm = g.iter().map(|v| v * v).sum::<f64>().sqrt();
        let record = (grad_norm, observed.to_numbers());
        observe(Iterate {
            iteration,
            grad_norm,
            observed,
        })?;
        if iteration >= average_from {
            for (a, x) in state.average.iter_mut().zip(&state.x) {
                *a += x / averaged as f64;
            }
        }
        state.step(learning_rate(iteration), &g);
        let state = &*state;
        journal.record(&inputs, record.to_numbers(), Some(&|| Ok(state.to_bytes())))?;
    }
    let done = [run, iterations as f64, 1.0];
    let result = match live {
        Some(state) => {
            let mut v = state.x;
            v.extend_from_slice(&state.average);
            journal.record(&done, v.clone(), None)?;
            v
        }
        None => journal.replay(&done)?.ok_or_else(mismatch)?,
    };
    if result.len() != n + if averaged > 0 { n } else { 0 } {
        return Err(mismatch());
    }
    let (last, average) = result.split_at(n);
    Ok(Minimised {
        last: last.to_vec(),
        average: average.to_vec(),
    })
}

fn mismatch() -> crate::Error {
    crate::Error::input(
        "the checkpoint does not match this run (an Adam record is missing or has the wrong length); resume with the command, config and options that started it",
    )
}

/// How a fixed-length run ended: at a plateau of its `losses` ([`plateaued`]) or at its
/// iteration limit, after `evaluations` evaluations, with the last gradient's norm.
pub fn convergence(losses: &[f64], grad_norm: f64, evaluations: usize) -> super::Convergence {
    let stop = if plateaued(losses) {
        super::FitStop::LossPlateau
    } else {
        super::FitStop::IterationLimit
    };
    super::Convergence {
        converged: stop.converged(),
        stop,
        grad_norm,
        evaluations,
        iterations: evaluations,
    }
}

/// Whether a fixed-length run's loss has stopped decreasing: the mean over the last third is lower
/// than over the third before by at most 1 % of the whole run's decrease (its largest loss minus the
/// last third's mean) plus twice the standard error of the difference (the losses of stochastic
/// iterations scatter). Needs at least 6 losses.
pub fn plateaued(losses: &[f64]) -> bool {
    let n = losses.len() / 3;
    if n < 2 {
        return false;
    }
    let stats = |s: &[f64]| {
        let m = s.iter().sum::<f64>() / s.len() as f64;
        let v = s.iter().map(|x| (x - m).powi(2)).sum::<f64>() / (s.len() as f64 - 1.0);
        (m, v / s.len() as f64)
    };
    let (before, v1) = stats(&losses[losses.len() - 2 * n..losses.len() - n]);
    let (last, v2) = stats(&losses[losses.len() - n..]);
    let top = losses.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
    before - last <= 0.01 * (top - last).abs() + 2.0 * (v1 + v2).sqrt()
}

#[cfg(test)]
mod tests {
    use super::super::journal::{Entry, Saver};
    use super::*;
    use std::sync::{Arc, Mutex};

    type Saves = Arc<Mutex<Vec<(Vec<Entry>, Option<Vec<u8>>)>>>;

    /// 400 steps on a quadratic bowl, observed and recorded in `journal`: the observations and
    /// the result.
    fn bowl(journal: &Journal) -> (Vec<f64>, Minimised) {
        let target = [1.0, -2.0, 0.5];
        let mut seen = Vec::new();
        let m = minimise(
            &[0.0; 3],
            400,
            &|it| 0.05 / (1.0 + it as f64 / 200.0),
            300,
            journal,
            &mut |_, x| {
                let d = x - tensor(&target, &device());
                let l = (d.clone() * d).sum().reshape([1]);
                let v = values(&l)[0];
                Ok((l, v))
            },
            &mut |it| {
                seen.push(it.observed);
                Ok(())
            },
        )
        .unwrap();
        (seen, m)
    }

    fn saving(every: u64) -> (Journal, Saves) {
        let saves: Saves = Arc::default();
        let s = saves.clone();
        let save = Box::new(move |saved: &super::super::journal::Saved<'_>| {
            s.lock()
                .unwrap()
                .push((saved.entries.to_vec(), saved.snapshot.map(|b| b.to_vec())));
            Ok(())
        });
        let j = Journal::new(
            Saver {
                every: Some(every),
                save,
            },
            vec![],
            None,
        );
        (j, saves)
    }

    /// A quadratic bowl reaches its minimum, the observer sees every iteration, and the plateau rule
    /// tells a still-falling loss from a flat one.
    #[test]
    fn quadratic_and_plateau() {
        let (seen, m) = bowl(&Journal::default());
        assert_eq!(seen.len(), 400);
        for (x, t) in [(&m.last, [1.0, -2.0, 0.5]), (&m.average, [1.0, -2.0, 0.5])] {
            for (a, b) in x.iter().zip(&t) {
                assert!((a - b).abs() < 1e-3, "{x:?}");
            }
        }
        assert!(plateaued(&seen));
        assert!(!plateaued(&seen[..30]), "still falling: {:?}", &seen[..30]);
    }

    /// A run resumed from any of its saves (Adam's moments included) observes the same losses and
    /// ends with the same bits as the uninterrupted run; a finished run replays without a step.
    #[test]
    fn resumed_runs_equal_the_uninterrupted_one() {
        let (seen, whole) = bowl(&Journal::default());
        let (journal, saves) = saving(37);
        bowl(&journal);
        let saves = saves.lock().unwrap().clone();
        assert_eq!(saves.len(), 10);
        for (entries, snapshot) in saves.into_iter().chain([(journal.entries(), None)]) {
            let at = entries.len();
            let resumed = Journal::new(
                Saver {
                    every: None,
                    save: Box::new(|_| Ok(())),
                },
                entries,
                snapshot,
            );
            let (seen_r, m) = bowl(&resumed);
            assert_eq!(seen_r, seen, "observations after resuming at {at}");
            assert_eq!(m.last, whole.last, "variables after resuming at {at}");
            assert_eq!(m.average, whole.average, "average after resuming at {at}");
        }
    }
}
