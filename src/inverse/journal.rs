//! Resumable fits and designs: the costly, deterministic results a fit asked for, in the order it
//! asked for them, saved as it goes. A killed fit started again with the same inputs replays them
//! instead of recomputing them (its optimiser redoes only its own cheap arithmetic) and continues
//! to the same bits as an uninterrupted run.
//!
//! Two kinds of record: an *entry* (an objective's value and gradient, an uncertainty, an Adam
//! iteration's observation), checked on replay by a hash of the inputs that asked for it; and a
//! *snapshot*, the state of a driver that cannot be replayed cheaply (Adam's variables and moments
//! over a million grid coefficients), valid where the saved entries end.

use std::sync::Mutex;
use std::time::{Duration, Instant};

/// One recorded result: the hash of its inputs and its numbers.
#[derive(Clone, Debug, PartialEq)]
pub struct Entry {
    pub key: u64,
    pub values: Vec<f64>,
}

/// What a save writes: every entry so far and, when a driver is part-way, its state after the last.
pub struct Saved<'a> {
    pub entries: &'a [Entry],
    pub snapshot: Option<&'a [u8]>,
}

/// What writes a save.
pub type Save = Box<dyn Fn(&Saved<'_>) -> crate::Result<()> + Send + Sync>;

/// Where and how often a journal is saved.
pub struct Saver {
    /// Save after this many new entries; `None`: every two minutes.
    pub every: Option<u64>,
    pub save: Save,
}

/// The record of one fit (see the module docs). [`Journal::default`] keeps nothing: a run that
/// cannot be resumed.
#[derive(Default)]
pub struct Journal {
    inner: Mutex<Inner>,
    saver: Option<Saver>,
}

#[derive(Default)]
struct Inner {
    entries: Vec<Entry>,
    /// The next entry to replay; at `entries.len()` the run is live.
    cursor: usize,
    /// A loaded snapshot, handed to the driver that reaches the end of the replayed entries.
    snapshot: Option<Vec<u8>>,
    unsaved: u64,
    saved_when: Option<Instant>,
}

/// A hash of the inputs' bits (FNV-1a), so a replay that asks for other inputs is caught.
pub fn key(inputs: &[f64]) -> u64 {
    let mut h: u64 = 0xcbf2_9ce4_8422_2325;
    for x in inputs {
        for b in x.to_bits().to_le_bytes() {
            h = (h ^ b as u64).wrapping_mul(0x0000_0100_0000_01b3);
        }
    }
    h
}

impl Journal {
    /// A journal saved through `saver`, replaying `entries` (and then handing out `snapshot`)
    /// from an earlier run of the same fit; empty for a fresh run.
    pub fn new(saver: Saver, entries: Vec<Entry>, snapshot: Option<Vec<u8>>) -> Self {
        Journal {
            inner: Mutex::new(Inner {
                entries,
                snapshot,
                ..Inner::default()
            }),
            saver: Some(saver),
        }
    }

    fn lock(&self) -> std::sync::MutexGuard<'_, Inner> {
        self.inner.lock().unwrap_or_else(|e| e.into_inner())
    }

    /// The next recorded entry, if the run is still replaying; it must have been asked for with
    /// the same `inputs`.
    pub fn replay(&self, inputs: &[f64]) -> crate::Result<Option<Vec<f64>>> {
        let mut st = self.lock();
        let Some(e) = st.entries.get(st.cursor) else {
            return Ok(None);
        };
        if e.key != key(inputs) {
            return Err(crate::Error::input(format!(
                "the checkpoint does not match this run: its record {} was made for other inputs; resume with the command, config and options that started it",
                st.cursor
            )));
        }
        let values = e.values.clone();
        st.cursor += 1;
        Ok(Some(values))
    }

    /// Record a live result asked for with `inputs`, and save if a save is due; `snapshot` gives
    /// the caller's state after this entry when it cannot be rebuilt by replaying entries (`None`
    /// when it can).
    pub fn record(
        &self,
        inputs: &[f64],
        values: Vec<f64>,
        snapshot: Option<&dyn Fn() -> crate::Result<Vec<u8>>>,
    ) -> crate::Result<()> {
        // a journal that is never saved has nothing to keep (and nothing to replay)
        let Some(saver) = &self.saver else {
            return Ok(());
        };
        let mut st = self.lock();
        st.entries.push(Entry {
            key: key(inputs),
            values,
        });
        st.cursor = st.entries.len();
        st.unsaved += 1;
        let when = *st.saved_when.get_or_insert_with(Instant::now);
        let due = match saver.every {
            Some(n) => st.unsaved >= n.max(1),
            None => when.elapsed() >= Duration::from_secs(120),
        };
        if due {
            let state = snapshot.map(|f| f()).transpose()?;
            (saver.save)(&Saved {
                entries: &st.entries,
                snapshot: state.as_deref(),
            })?;
            st.unsaved = 0;
            st.saved_when = Some(Instant::now());
        }
        Ok(())
    }

    /// The recorded result for `inputs`, or `compute()`'s, recorded.
    pub fn recall(
        &self,
        inputs: &[f64],
        compute: impl FnOnce() -> crate::Result<Vec<f64>>,
    ) -> crate::Result<Vec<f64>> {
        if let Some(v) = self.replay(inputs)? {
            return Ok(v);
        }
        let v = compute()?;
        self.record(inputs, v.clone(), None)?;
        Ok(v)
    }

    /// The saved driver state where the replayed entries end: once, and only when every entry
    /// has been replayed.
    pub fn take_snapshot(&self) -> Option<Vec<u8>> {
        let mut st = self.lock();
        if st.cursor < st.entries.len() {
            return None;
        }
        st.snapshot.take()
    }

    /// The entries recorded so far (replayed or new).
    pub fn entries(&self) -> Vec<Entry> {
        self.lock().entries.clone()
    }
}

/// Values that travel through a journal entry as numbers.
pub trait Numbers: Sized {
    fn to_numbers(&self) -> Vec<f64>;
    fn from_numbers(v: &[f64]) -> Option<Self>;
}

impl Numbers for f64 {
    fn to_numbers(&self) -> Vec<f64> {
        vec![*self]
    }
    fn from_numbers(v: &[f64]) -> Option<Self> {
        match v {
            [x] => Some(*x),
            _ => None,
        }
    }
}

impl Numbers for Vec<f64> {
    fn to_numbers(&self) -> Vec<f64> {
        self.clone()
    }
    fn from_numbers(v: &[f64]) -> Option<Self> {
        Some(v.to_vec())
    }
}

/// A number first, then the rest.
impl<T: Numbers> Numbers for (f64, T) {
    fn to_numbers(&self) -> Vec<f64> {
        let mut v = vec![self.0];
        v.extend(self.1.to_numbers());
        v
    }
    fn from_numbers(v: &[f64]) -> Option<Self> {
        let (first, rest) = v.split_first()?;
        Some((*first, T::from_numbers(rest)?))
    }
}

/// The recorded result for `inputs` as a `T`, or `compute()`'s, recorded.
pub fn recall<T: Numbers>(
    journal: &Journal,
    inputs: &[f64],
    compute: impl FnOnce() -> crate::Result<T>,
) -> crate::Result<T> {
    let v = journal.recall(inputs, || compute().map(|t| t.to_numbers()))?;
    T::from_numbers(&v).ok_or_else(|| {
        crate::Error::input(
            "the checkpoint does not match this run (a record has the wrong length); resume with the command, config and options that started it",
        )
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::sync::Arc;

    /// A fresh run records, a second run replays the same entries without computing, a run that
    /// asks for other inputs is refused, and saves happen every `every` entries with the snapshot.
    #[test]
    fn replays_checks_and_saves() {
        let saves = Arc::new(Mutex::new(Vec::new()));
        let s = saves.clone();
        let j = Journal::new(
            Saver {
                every: Some(2),
                save: Box::new(move |saved| {
                    s.lock()
                        .unwrap()
                        .push((saved.entries.to_vec(), saved.snapshot.map(|b| b.to_vec())));
                    Ok(())
                }),
            },
            vec![],
            None,
        );
        for i in 0..5 {
            let x = i as f64;
            let v: (f64, Vec<f64>) = recall(&j, &[x], || Ok((x * x, vec![2.0 * x]))).unwrap();
            assert_eq!(v, (x * x, vec![2.0 * x]));
        }
        j.record(&[9.0], vec![1.0], Some(&|| Ok(vec![7u8])))
            .unwrap();
        let saves = saves.lock().unwrap().clone();
        assert_eq!(saves.len(), 3);
        assert_eq!(saves[0].0.len(), 2);
        assert_eq!(saves[2], (saves[2].0.clone(), Some(vec![7u8])));
        let (entries, snapshot) = saves[2].clone();
        assert_eq!(entries.len(), 6);

        let replay = Journal::new(
            Saver {
                every: None,
                save: Box::new(|_| Ok(())),
            },
            entries.clone(),
            snapshot,
        );
        for i in 0..5 {
            let x = i as f64;
            let v: (f64, Vec<f64>) =
                recall(&replay, &[x], || panic!("entry {i} was recomputed")).unwrap();
            assert_eq!(v, (x * x, vec![2.0 * x]));
        }
        assert_eq!(replay.take_snapshot(), None, "an entry is still to replay");
        assert_eq!(replay.replay(&[9.0]).unwrap(), Some(vec![1.0]));
        assert_eq!(replay.take_snapshot(), Some(vec![7u8]));
        assert_eq!(replay.take_snapshot(), None);
        assert_eq!(replay.replay(&[10.0]).unwrap(), None, "live after the end");

        let other = Journal::new(
            Saver {
                every: None,
                save: Box::new(|_| Ok(())),
            },
            entries,
            None,
        );
        let e = other.replay(&[0.5]).unwrap_err().to_string();
        assert!(e.contains("does not match"), "{e}");
    }
}
