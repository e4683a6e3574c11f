//! Shard state files (`state.bin`): the header of the run and the engine blocks of one shard, so
//! that `lightpath merge` reproduces the single run bit for bit. A fit's or design's checkpoint
//! (its [`Journal`](crate::inverse::journal::Journal)) is saved in the same style, see
//! [`write_journal`].
//!
//! Layout (little endian): `LPSTATE2`, `u64` header length, header JSON, `u64` block count, then per
//! block `start, len, n_sum, n_sq, n_kept` (`u64`) and the `f64` data of `sum` (re, im), `sq`,
//! `kept` (re, im); last the CRC-32 of everything before it (`u32`), so a changed bit anywhere —
//! in the numbers or in the header that says what they are — is refused, not merged.

use crate::math::C64;
use crate::mc::Block;
use serde::{Deserialize, Serialize};
use std::io::{Read, Write};
use std::path::Path;

const MAGIC: &[u8; 8] = b"LPSTATE2";
/// The first format (no checksum): recognised only to say so.
const MAGIC_V1: &[u8; 8] = b"LPSTATE1";

/// What a shard computed and for which run.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct StateHeader {
    #[serde(default)]
    pub format_version: u32,
    /// `covariance`, `memory-effect`, `speckle` or `wave`.
    pub kind: String,
    /// The config the run used (after command-line overrides), as JSON: a speckle scene's
    /// `Config` or a render's `RenderConfig`, as `kind` says.
    pub config: serde_json::Value,
    pub seed: u64,
    pub chunk_paths: u64,
    pub chunks: u64,
    pub shard: [u64; 2],
    pub version: String,
}

impl StateHeader {
    /// Whether two shards belong to the same run (everything but the shard index agrees).
    pub fn same_run(&self, other: &StateHeader) -> bool {
        (
            &self.kind,
            &self.config,
            self.seed,
            self.chunk_paths,
            self.chunks,
            self.shard[1],
            &self.version,
        ) == (
            &other.kind,
            &other.config,
            other.seed,
            other.chunk_paths,
            other.chunks,
            other.shard[1],
            &other.version,
        )
    }
}

pub fn write_state(path: &Path, header: &StateHeader, blocks: &[Block]) -> std::io::Result<()> {
    write_framed(path, MAGIC, header, |buf| {
        buf.extend_from_slice(&(blocks.len() as u64).to_le_bytes());
        for b in blocks {
            for v in [
                b.start,
                b.len,
                b.sum.len() as u64,
                b.sq.len() as u64,
                b.kept.len() as u64,
            ] {
                buf.extend_from_slice(&v.to_le_bytes());
            }
            for z in &b.sum {
                buf.extend_from_slice(&z.re.to_le_bytes());
                buf.extend_from_slice(&z.im.to_le_bytes());
            }
            for v in &b.sq {
                buf.extend_from_slice(&v.to_le_bytes());
            }
            for z in &b.kept {
                buf.extend_from_slice(&z.re.to_le_bytes());
                buf.extend_from_slice(&z.im.to_le_bytes());
            }
        }
    })
}

/// Write `magic`, the header as JSON after its `u64` length, what `body` appends, and the CRC-32
/// of all of it, to `path` atomically.
fn write_framed(
    path: &Path,
    magic: &[u8; 8],
    header: &impl Serialize,
    body: impl FnOnce(&mut Vec<u8>),
) -> std::io::Result<()> {
    let mut buf = Vec::new();
    buf.extend_from_slice(magic);
    let h = serde_json::to_vec(header).map_err(std::io::Error::other)?;
    buf.extend_from_slice(&(h.len() as u64).to_le_bytes());
    buf.extend_from_slice(&h);
    body(&mut buf);
    let crc = crc32fast::hash(&buf);
    buf.extend_from_slice(&crc.to_le_bytes());
    crate::io::write_atomic(path, &buf)
}

/// The header of a file [`write_framed`] wrote (its magic already checked), and a cursor on the
/// body after it; the checksum must match.
fn read_framed<H: serde::de::DeserializeOwned>(data: &[u8]) -> crate::Result<(H, Cursor<'_>)> {
    let body = checked_body(data)?;
    let mut c = Cursor { data: body, pos: 8 };
    let hl = c.len()?;
    let header = serde_json::from_slice(c.take(hl)?).map_err(|e| format!("bad header: {e}"))?;
    Ok((header, c))
}

struct Cursor<'a> {
    data: &'a [u8],
    pos: usize,
}

impl Cursor<'_> {
    fn take(&mut self, n: usize) -> crate::Result<&[u8]> {
        let end = self
            .pos
            .checked_add(n)
            .filter(|&e| e <= self.data.len())
            .ok_or("file is truncated")?;
        let s = &self.data[self.pos..end];
        self.pos = end;
        Ok(s)
    }
    fn u64(&mut self) -> crate::Result<u64> {
        Ok(u64::from_le_bytes(
            self.take(8)?.try_into().expect("8 bytes"),
        ))
    }
    fn f64(&mut self) -> crate::Result<f64> {
        Ok(f64::from_le_bytes(
            self.take(8)?.try_into().expect("8 bytes"),
        ))
    }
    fn len(&mut self) -> crate::Result<usize> {
        let n = self.u64()?;
        if n as usize > self.data.len() {
            return Err("file is corrupt (length field too large)".into());
        }
        Ok(n as usize)
    }
}

pub fn read_state(path: &Path) -> crate::Result<(StateHeader, Vec<Block>)> {
    let mut data = Vec::new();
    std::fs::File::open(path)
        .and_then(|mut f| f.read_to_end(&mut data))
        .map_err(|e| format!("cannot read {}: {e}", path.display()))?;
    let parse = || -> crate::Result<(StateHeader, Vec<Block>)> {
        if data.starts_with(MAGIC_V1) {
            return Err("written by an older lightpath (no checksum); run the shard again".into());
        }
        if !data.starts_with(MAGIC) {
            return Err("not a lightpath state file".into());
        }
        let (header, mut c): (StateHeader, _) =
            read_framed(&data).map_err(|e| format!("{e}; run the shard again"))?;
        let n = c.len()?;
        let mut blocks = Vec::with_capacity(n.min(1024));
        for _ in 0..n {
            let (start, len) = (c.u64()?, c.u64()?);
            let (ns, nq, nk) = (c.len()?, c.len()?, c.len()?);
            let mut sum = Vec::with_capacity(ns);
            for _ in 0..ns {
                sum.push(C64::new(c.f64()?, c.f64()?));
            }
            let mut sq = Vec::with_capacity(nq);
            for _ in 0..nq {
                sq.push(c.f64()?);
            }
            let mut kept = Vec::with_capacity(nk);
            for _ in 0..nk {
                kept.push(C64::new(c.f64()?, c.f64()?));
            }
            blocks.push(Block {
                start,
                len,
                sum,
                sq,
                kept,
            });
        }
        if c.pos != c.data.len() {
            return Err("file is corrupt (bytes after the last block)".into());
        }
        Ok((header, blocks))
    };
    parse().map_err(|e| crate::Error::input(format!("{}: {e}", path.display())))
}

const JOURNAL_MAGIC: &[u8; 8] = b"LPJOURN1";

/// Which fit or design a journal belongs to.
#[derive(Clone, Debug, Serialize, Deserialize, PartialEq)]
pub struct JournalHeader {
    /// `fit` or `design`.
    pub kind: String,
    /// Everything the run's results depend on (config, target, options), as JSON.
    pub identity: serde_json::Value,
    pub version: String,
}

/// A fit's or design's checkpoint. Layout (little endian): `LPJOURN1`, `u64` header length, header
/// JSON, `u64` entry count, per entry its `u64` key, `u64` length and `f64` values, then a `u64`
/// snapshot length (`u64::MAX`: none) and its bytes; last the CRC-32 of everything before it.
pub fn write_journal(
    path: &Path,
    header: &JournalHeader,
    saved: &crate::inverse::journal::Saved<'_>,
) -> std::io::Result<()> {
    write_framed(path, JOURNAL_MAGIC, header, |buf| {
        buf.extend_from_slice(&(saved.entries.len() as u64).to_le_bytes());
        for e in saved.entries {
            buf.extend_from_slice(&e.key.to_le_bytes());
            buf.extend_from_slice(&(e.values.len() as u64).to_le_bytes());
            for v in &e.values {
                buf.extend_from_slice(&v.to_le_bytes());
            }
        }
        match saved.snapshot {
            Some(b) => {
                buf.extend_from_slice(&(b.len() as u64).to_le_bytes());
                buf.extend_from_slice(b);
            }
            None => buf.extend_from_slice(&u64::MAX.to_le_bytes()),
        }
    })
}

/// A checkpoint written by [`write_journal`]: its header, entries and snapshot.
pub type Journaled = (
    JournalHeader,
    Vec<crate::inverse::journal::Entry>,
    Option<Vec<u8>>,
);

pub fn read_journal(path: &Path) -> crate::Result<Journaled> {
    let data = std::fs::read(path).map_err(|e| format!("cannot read {}: {e}", path.display()))?;
    let parse = || -> crate::Result<Journaled> {
        if !data.starts_with(JOURNAL_MAGIC) {
            return Err("not the checkpoint of a fit or design".into());
        }
        let (header, mut c): (JournalHeader, _) = read_framed(&data)?;
        let n = c.len()?;
        let mut entries = Vec::with_capacity(n.min(1 << 16));
        for _ in 0..n {
            let key = c.u64()?;
            let len = c.len()?;
            let values = (0..len).map(|_| c.f64()).collect::<crate::Result<_>>()?;
            entries.push(crate::inverse::journal::Entry { key, values });
        }
        let snapshot = match c.u64()? {
            u64::MAX => None,
            len if len as usize <= c.data.len() => Some(c.take(len as usize)?.to_vec()),
            _ => return Err("file is corrupt (length field too large)".into()),
        };
        if c.pos != c.data.len() {
            return Err("file is corrupt (bytes after the snapshot)".into());
        }
        Ok((header, entries, snapshot))
    };
    parse().map_err(|e| crate::Error::input(format!("{}: {e}", path.display())))
}

/// `data` without its trailing CRC-32, which must match.
fn checked_body(data: &[u8]) -> crate::Result<&[u8]> {
    let body = data
        .len()
        .checked_sub(4)
        .filter(|&n| n >= 8)
        .ok_or("file is truncated")?;
    let stored = u32::from_le_bytes(data[body..].try_into().expect("4 bytes"));
    if crc32fast::hash(&data[..body]) != stored {
        return Err(
            "checksum mismatch: the file was changed or damaged after it was written".into(),
        );
    }
    Ok(&data[..body])
}

/// Write `bytes` to `path` through a temporary file, so a reader never sees half a file.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let tmp = crate::io::staging_name(path);
    {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all().ok();
    }
    std::fs::rename(&tmp, path)
}
