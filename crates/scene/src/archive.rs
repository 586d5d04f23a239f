//! A small binary container of named little-endian arrays, used for checkpoints.
//!
//! Layout (version 1), all integers little-endian:
//!
//! ```text
//! "TSPLCKPT"  u32 version  u32 entry count
//! per entry:  u16 name length, name (UTF-8), u8 type (1 f32, 2 u32, 3 u64, 4 f64, 5 UTF-8 text),
//!             u64 element count, the elements
//! trailer:    u64 checksum of every byte before it, "TSPLEND\0"
//! ```
//!
//! Files are written atomically ([`crate::atomic`]). Reading checks the end marker
//! and the checksum before anything else, so a truncated or damaged file is an
//! error naming the file, never a panic or a silently partial state.

use crate::{atomic, rng::mix, Error, Result};
use std::borrow::Cow;
use std::collections::HashMap;
use std::io::Write;
use std::path::{Path, PathBuf};

const MAGIC: &[u8; 8] = b"TSPLCKPT";
const END: &[u8; 8] = b"TSPLEND\0";
const VERSION: u32 = 1;

/// A streaming 64-bit hash (SplitMix64's finaliser over 8-byte words) for
/// checksums and input fingerprints. Not cryptographic.
#[derive(Clone, Debug)]
pub struct Hasher {
    h: u64,
    len: u64,
}

impl Default for Hasher {
    fn default() -> Self {
        Hasher { h: 0x5452_414E_5353_504C, len: 0 }
    }
}

impl Hasher {
    /// Adds one 64-bit word.
    pub fn u64(&mut self, v: u64) -> &mut Self {
        self.h = mix(self.h ^ v);
        self.len += 1;
        self
    }

    /// Adds bytes (length-prefixed, so `"ab","c"` and `"a","bc"` differ).
    pub fn bytes(&mut self, b: &[u8]) -> &mut Self {
        self.u64(b.len() as u64);
        let rest = self.words(b);
        if !rest.is_empty() {
            self.u64(padded_word(rest));
        }
        self
    }

    /// Adds the whole little-endian 8-byte words of `b`; returns the bytes left over.
    fn words<'b>(&mut self, b: &'b [u8]) -> &'b [u8] {
        let mut chunks = b.chunks_exact(8);
        for c in &mut chunks {
            self.u64(u64::from_le_bytes(c.try_into().expect("8 bytes")));
        }
        chunks.remainder()
    }

    /// Adds text.
    pub fn str(&mut self, s: &str) -> &mut Self {
        self.bytes(s.as_bytes())
    }

    /// Adds floats by their bit patterns (length-prefixed).
    pub fn f32s(&mut self, v: &[f32]) -> &mut Self {
        self.u64(v.len() as u64);
        let mut pairs = v.chunks_exact(2);
        for p in &mut pairs {
            self.u64(p[0].to_bits() as u64 | (p[1].to_bits() as u64) << 32);
        }
        if let [x] = pairs.remainder() {
            self.u64(x.to_bits() as u64);
        }
        self
    }

    /// The hash so far.
    pub fn finish(&self) -> u64 {
        mix(self.h ^ self.len)
    }
}

/// The file checksum, fed in pieces: [`Hasher`] over the bytes as 8-byte words
/// (the last one zero-padded), then the length.
#[derive(Clone, Debug, Default)]
struct Checksum {
    h: Hasher,
    tail: [u8; 8],
    n: usize,
    len: u64,
}

impl Checksum {
    fn update(&mut self, mut b: &[u8]) {
        self.len += b.len() as u64;
        if self.n > 0 {
            let k = (8 - self.n).min(b.len());
            self.tail[self.n..self.n + k].copy_from_slice(&b[..k]);
            self.n += k;
            b = &b[k..];
            if self.n < 8 {
                return;
            }
            self.h.u64(u64::from_le_bytes(self.tail));
            self.n = 0;
        }
        let rest = self.h.words(b);
        self.tail[..rest.len()].copy_from_slice(rest);
        self.n = rest.len();
    }

    fn finish(mut self) -> u64 {
        if self.n > 0 {
            self.h.u64(padded_word(&self.tail[..self.n]));
        }
        self.h.u64(self.len).finish()
    }
}

/// Up to 8 bytes as a little-endian word, zero-padded.
fn padded_word(b: &[u8]) -> u64 {
    let mut w = [0u8; 8];
    w[..b.len()].copy_from_slice(b);
    u64::from_le_bytes(w)
}

/// Checksum of a whole byte string.
fn checksum(b: &[u8]) -> u64 {
    let mut c = Checksum::default();
    c.update(b);
    c.finish()
}

/// A writer that feeds the checksum with everything it writes.
struct Sink<'w> {
    w: &'w mut dyn Write,
    sum: Checksum,
}

impl Sink<'_> {
    fn put(&mut self, b: &[u8]) -> std::io::Result<()> {
        self.sum.update(b);
        self.w.write_all(b)
    }

    /// Writes values in blocks (no copy of the whole array).
    fn values<T: Copy, const N: usize>(&mut self, v: &[T], le: impl Fn(T) -> [u8; N]) -> std::io::Result<()> {
        self.put(&(v.len() as u64).to_le_bytes())?;
        let mut buf = Vec::with_capacity(N << 13);
        for block in v.chunks(1 << 13) {
            buf.clear();
            block.iter().for_each(|&x| buf.extend_from_slice(&le(x)));
            self.put(&buf)?;
        }
        Ok(())
    }
}

/// Borrowed or owned array data of one entry.
#[derive(Clone, Debug)]
enum Slot<'a> {
    F32(Cow<'a, [f32]>),
    U32(Cow<'a, [u32]>),
    U64(Cow<'a, [u64]>),
    F64(Cow<'a, [f64]>),
    Text(Cow<'a, str>),
}

impl Slot<'_> {
    fn code(&self) -> u8 {
        match self {
            Slot::F32(_) => 1,
            Slot::U32(_) => 2,
            Slot::U64(_) => 3,
            Slot::F64(_) => 4,
            Slot::Text(_) => 5,
        }
    }
}

/// Collects named arrays (borrowed where possible) and writes them as one file.
#[derive(Clone, Debug, Default)]
pub struct Writer<'a> {
    entries: Vec<(String, Slot<'a>)>,
}

impl<'a> Writer<'a> {
    pub fn new() -> Self {
        Writer::default()
    }
    pub fn f32(&mut self, name: impl Into<String>, v: impl Into<Cow<'a, [f32]>>) -> &mut Self {
        self.entries.push((name.into(), Slot::F32(v.into())));
        self
    }
    pub fn u32(&mut self, name: impl Into<String>, v: impl Into<Cow<'a, [u32]>>) -> &mut Self {
        self.entries.push((name.into(), Slot::U32(v.into())));
        self
    }
    pub fn u64(&mut self, name: impl Into<String>, v: impl Into<Cow<'a, [u64]>>) -> &mut Self {
        self.entries.push((name.into(), Slot::U64(v.into())));
        self
    }
    pub fn f64(&mut self, name: impl Into<String>, v: impl Into<Cow<'a, [f64]>>) -> &mut Self {
        self.entries.push((name.into(), Slot::F64(v.into())));
        self
    }
    pub fn text(&mut self, name: impl Into<String>, v: impl Into<Cow<'a, str>>) -> &mut Self {
        self.entries.push((name.into(), Slot::Text(v.into())));
        self
    }
    /// One 64-bit integer.
    pub fn scalar(&mut self, name: impl Into<String>, v: u64) -> &mut Self {
        self.u64(name, vec![v])
    }

    /// Streams the file into `w`; returns the checksum.
    fn emit(&self, w: &mut dyn Write) -> std::io::Result<u64> {
        let mut s = Sink { w, sum: Checksum::default() };
        s.put(MAGIC)?;
        s.put(&VERSION.to_le_bytes())?;
        s.put(&(self.entries.len() as u32).to_le_bytes())?;
        for (name, slot) in &self.entries {
            assert!(name.len() <= u16::MAX as usize, "archive entry name too long");
            s.put(&(name.len() as u16).to_le_bytes())?;
            s.put(name.as_bytes())?;
            s.put(&[slot.code()])?;
            match slot {
                Slot::F32(v) => s.values(v, f32::to_le_bytes)?,
                Slot::U32(v) => s.values(v, u32::to_le_bytes)?,
                Slot::U64(v) => s.values(v, u64::to_le_bytes)?,
                Slot::F64(v) => s.values(v, f64::to_le_bytes)?,
                Slot::Text(v) => s.values(v.as_bytes(), |b: u8| [b])?,
            }
        }
        let Sink { w, sum } = s;
        let sum = sum.finish();
        w.write_all(&sum.to_le_bytes())?;
        w.write_all(END)?;
        Ok(sum)
    }

    /// The file's bytes.
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut out = Vec::new();
        self.emit(&mut out).expect("writing to memory");
        out
    }

    /// Writes the file atomically (streamed to a temporary name, then renamed);
    /// returns its checksum.
    pub fn write(&self, path: &Path) -> Result<u64> {
        let mut sum = 0;
        atomic::write_with(path, |w| {
            sum = self.emit(w)?;
            Ok(())
        })?;
        Ok(sum)
    }
}

/// Owned array data read back.
#[derive(Clone, Debug, PartialEq)]
enum Data {
    F32(Vec<f32>),
    U32(Vec<u32>),
    U64(Vec<u64>),
    F64(Vec<f64>),
    Text(String),
}

/// A container read from a file; every lookup error names the file and the entry.
#[derive(Clone, Debug)]
pub struct Archive {
    path: PathBuf,
    checksum: u64,
    entries: HashMap<String, Data>,
}

macro_rules! getter {
    ($fn:ident, $variant:ident, $t:ty, $tn:literal) => {
        /// The entry `name`, which must have this element type.
        pub fn $fn(&self, name: &str) -> Result<&[$t]> {
            match self.entries.get(name) {
                Some(Data::$variant(v)) => Ok(v),
                Some(_) => Err(self.err(format!("entry {name:?} is not of type {}", $tn))),
                None => Err(self.missing(name)),
            }
        }
    };
}

impl Archive {
    /// Reads and checks a file.
    pub fn read(path: &Path) -> Result<Self> {
        Self::parse(&atomic::read(path)?, path)
    }

    /// Parses file bytes; `path` is used in error messages.
    pub fn parse(bytes: &[u8], path: &Path) -> Result<Self> {
        let err = |m: &str| Error::format(path, m.to_string());
        if bytes.len() < 8 || &bytes[..8] != MAGIC {
            return Err(err("not a transsplat checkpoint file (bad magic)"));
        }
        if bytes.len() < 32 || &bytes[bytes.len() - 8..] != END {
            return Err(err("checkpoint file is truncated (no end marker): it was not completely written"));
        }
        let body = &bytes[..bytes.len() - 16];
        let stored = u64::from_le_bytes(bytes[bytes.len() - 16..bytes.len() - 8].try_into().expect("8"));
        if checksum(body) != stored {
            return Err(err("checkpoint file is damaged (checksum mismatch)"));
        }
        let version = u32::from_le_bytes(body[8..12].try_into().expect("4"));
        if version != VERSION {
            return Err(Error::format(
                path,
                format!("checkpoint format version {version} is not supported (this build reads {VERSION})"),
            ));
        }
        let count = u32::from_le_bytes(body[12..16].try_into().expect("4"));
        let mut pos = 16usize;
        let mut take = |n: usize| -> Result<&[u8]> {
            let end = pos
                .checked_add(n)
                .filter(|&e| e <= body.len())
                .ok_or_else(|| err("entry overruns the file"))?;
            let s = &body[pos..end];
            pos = end;
            Ok(s)
        };
        let mut entries = HashMap::new();
        for _ in 0..count {
            let nl = u16::from_le_bytes(take(2)?.try_into().expect("2")) as usize;
            let name =
                std::str::from_utf8(take(nl)?).map_err(|_| err("entry name is not UTF-8"))?.to_string();
            let code = take(1)?[0];
            let len = u64::from_le_bytes(take(8)?.try_into().expect("8"));
            let size: u64 = match code {
                1 | 2 => 4,
                3 | 4 => 8,
                5 => 1,
                c => return Err(Error::format(path, format!("entry {name:?} has unknown type {c}"))),
            };
            let nbytes = len.checked_mul(size).and_then(|b| usize::try_from(b).ok());
            let raw = take(nbytes.ok_or_else(|| err("entry size overflows"))?)?;
            let data = match code {
                1 => Data::F32(
                    raw.chunks_exact(4).map(|c| f32::from_le_bytes(c.try_into().expect("4"))).collect(),
                ),
                2 => Data::U32(
                    raw.chunks_exact(4).map(|c| u32::from_le_bytes(c.try_into().expect("4"))).collect(),
                ),
                3 => Data::U64(
                    raw.chunks_exact(8).map(|c| u64::from_le_bytes(c.try_into().expect("8"))).collect(),
                ),
                4 => Data::F64(
                    raw.chunks_exact(8).map(|c| f64::from_le_bytes(c.try_into().expect("8"))).collect(),
                ),
                _ => Data::Text(
                    std::str::from_utf8(raw)
                        .map_err(|_| Error::format(path, format!("entry {name:?} is not UTF-8 text")))?
                        .to_string(),
                ),
            };
            if entries.contains_key(&name) {
                return Err(Error::format(path, format!("entry {name:?} appears twice")));
            }
            entries.insert(name, data);
        }
        if pos != body.len() {
            return Err(err("trailing bytes after the last entry"));
        }
        Ok(Archive { path: path.to_path_buf(), checksum: stored, entries })
    }

    /// The file this was read from.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// The file's checksum (as returned by [`Writer::write`]).
    pub fn checksum(&self) -> u64 {
        self.checksum
    }

    /// Whether an entry exists.
    pub fn has(&self, name: &str) -> bool {
        self.entries.contains_key(name)
    }

    /// A format error about this file.
    pub fn err(&self, msg: impl Into<String>) -> Error {
        Error::format(&self.path, msg)
    }

    fn missing(&self, name: &str) -> Error {
        self.err(format!("checkpoint has no entry {name:?}"))
    }

    getter!(f32, F32, f32, "f32");
    getter!(u32, U32, u32, "u32");
    getter!(u64, U64, u64, "u64");
    getter!(f64, F64, f64, "f64");

    /// The text entry `name`.
    pub fn text(&self, name: &str) -> Result<&str> {
        match self.entries.get(name) {
            Some(Data::Text(v)) => Ok(v),
            Some(_) => Err(self.err(format!("entry {name:?} is not text"))),
            None => Err(self.missing(name)),
        }
    }

    /// The one-element u64 entry `name`.
    pub fn scalar(&self, name: &str) -> Result<u64> {
        match self.u64(name)? {
            [v] => Ok(*v),
            v => Err(self.err(format!("entry {name:?} has {} values, expected 1", v.len()))),
        }
    }

    /// The f32 entry `name`, which must have `len` values.
    pub fn f32_len(&self, name: &str, len: usize) -> Result<&[f32]> {
        let v = self.f32(name)?;
        if v.len() != len {
            return Err(self.err(format!("entry {name:?} has {} values, expected {len}", v.len())));
        }
        Ok(v)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn sample() -> Vec<u8> {
        let v = [1.5f32, -2.0, f32::MIN_POSITIVE];
        let mut w = Writer::new();
        w.f32("a", &v[..])
            .u32("b", vec![7u32, 8])
            .u64("c", vec![u64::MAX])
            .f64("d", vec![0.1f64])
            .text("e", "héllo")
            .scalar("s", 42);
        w.to_bytes()
    }

    #[test]
    fn round_trip() {
        let a = Archive::parse(&sample(), Path::new("x.ckpt")).unwrap();
        assert_eq!(a.f32("a").unwrap(), &[1.5, -2.0, f32::MIN_POSITIVE]);
        assert_eq!(a.u32("b").unwrap(), &[7, 8]);
        assert_eq!(a.u64("c").unwrap(), &[u64::MAX]);
        assert_eq!(a.f64("d").unwrap(), &[0.1]);
        assert_eq!(a.text("e").unwrap(), "héllo");
        assert_eq!(a.scalar("s").unwrap(), 42);
        assert!(a.f32("b").unwrap_err().to_string().contains("x.ckpt"));
        assert!(a.f32("zz").unwrap_err().to_string().contains("no entry \"zz\""));
        assert!(a.f32_len("a", 4).unwrap_err().to_string().contains("expected 4"));
    }

    #[test]
    fn every_truncation_and_any_flipped_byte_is_an_error_naming_the_file() {
        let bytes = sample();
        for cut in 0..bytes.len() {
            let e = Archive::parse(&bytes[..cut], Path::new("t.ckpt")).unwrap_err();
            assert!(e.to_string().starts_with("t.ckpt: "), "{e}");
        }
        for i in 0..bytes.len() {
            let mut b = bytes.clone();
            b[i] ^= 0x10;
            assert!(Archive::parse(&b, Path::new("f.ckpt")).is_err(), "flipped byte {i} went unnoticed");
        }
    }

    /// Pinned values: checkpoints and input fingerprints written by earlier builds must
    /// still verify, so the hash of given bytes must never change.
    #[test]
    fn hash_values_are_stable() {
        let bytes: Vec<u8> = (0..=20u8).collect();
        let got = [
            checksum(&bytes),
            checksum(b""),
            Hasher::default().bytes(&bytes).finish(),
            Hasher::default().str("abc").f32s(&[1.5, -2.0, 3.0]).u64(7).finish(),
        ];
        assert_eq!(
            got,
            [0x8884_69d7_6de8_97db, 0x32bb_040a_f63c_0964, 0xfbd9_afb3_ad88_bf8e, 0x513c_6e54_1881_19a1]
        );
    }

    #[test]
    fn a_repeated_entry_name_is_refused() {
        let mut w = Writer::new();
        w.f32("x", vec![1.0]).u32("y", vec![2]).text("x", "again");
        let e = Archive::parse(&w.to_bytes(), Path::new("dup.ckpt")).unwrap_err().to_string();
        assert!(e.contains("dup.ckpt") && e.contains("\"x\" appears twice"), "{e}");
    }

    #[test]
    fn hasher_separates_boundaries_and_values() {
        let h = |parts: &[&str]| {
            let mut h = Hasher::default();
            parts.iter().for_each(|p| {
                h.str(p);
            });
            h.finish()
        };
        assert_ne!(h(&["ab", "c"]), h(&["a", "bc"]));
        assert_ne!(Hasher::default().f32s(&[0.0]).finish(), Hasher::default().f32s(&[-0.0]).finish());
        // The streamed checksum does not depend on how the bytes are split.
        let bytes: Vec<u8> = (0..=255u8).collect();
        for cut in [0, 1, 7, 8, 9, 100] {
            let mut c = Checksum::default();
            c.update(&bytes[..cut]);
            c.update(&bytes[cut..cut.max(130)]);
            c.update(&bytes[cut.max(130)..]);
            assert_eq!(c.finish(), checksum(&bytes), "split at {cut}");
        }
        assert_ne!(checksum(b"abc"), checksum(b"abc\0"));
    }
}
