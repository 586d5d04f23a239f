//! Checkpoint archives: never panic or allocate past the input. An accepted archive
//! answers every getter for every entry it holds (the right type bit-exact against
//! the file's bytes, the wrong types as errors), and rebuilt with `archive::Writer`
//! it serialises to the same bytes and parses to the same arrays.
//!
//! The first byte picks a mode, because a checksum protects the file and random
//! mutations rarely get past it:
//!
//! - 0: the rest is a whole file, parsed as it is;
//! - 1: the rest is the body (header and entries); the checksum and end marker are
//!   appended, so the structure checks (counts, lengths, names, types) get exercised;
//! - 2: the rest drives a `Writer` (see [`build`]); its file must parse to the same arrays;
//! - 3: as 2, then a byte range of the body is changed or cut (the next 4 bytes say
//!   where and how) and the checksum recomputed before parsing.
#![no_main]

use libfuzzer_sys::fuzz_target;
use std::path::Path;
use transsplat_scene::archive::{Archive, Hasher, Writer};

const END: &[u8; 8] = b"TSPLEND\0";

/// The file checksum as archive.rs documents it: [`Hasher`] over the bytes as
/// little-endian 8-byte words (the last one zero-padded), then the length. Mode 2
/// checks this against what `Writer` stores, so a change of format shows up at once.
fn checksum(body: &[u8]) -> u64 {
    let mut h = Hasher::default();
    let mut words = body.chunks_exact(8);
    for w in &mut words {
        h.u64(u64::from_le_bytes(w.try_into().unwrap()));
    }
    let rest = words.remainder();
    if !rest.is_empty() {
        let mut w = [0u8; 8];
        w[..rest.len()].copy_from_slice(rest);
        h.u64(u64::from_le_bytes(w));
    }
    h.u64(body.len() as u64).finish()
}

fn with_trailer(body: &[u8]) -> Vec<u8> {
    let mut out = body.to_vec();
    out.extend_from_slice(&checksum(body).to_le_bytes());
    out.extend_from_slice(END);
    out
}

/// One entry's values, as written.
#[derive(Clone, Debug)]
enum Values {
    F32(Vec<f32>),
    U32(Vec<u32>),
    U64(Vec<u64>),
    F64(Vec<f64>),
    Text(String),
}

/// An independent walk over an accepted file's body (the layout in archive.rs's docs).
fn walk(body: &[u8]) -> Vec<(String, Values)> {
    let mut pos = 16;
    let mut take = |n: usize| {
        let s = &body[pos..pos + n];
        pos += n;
        s
    };
    let count = u32::from_le_bytes(body[12..16].try_into().unwrap());
    let mut out = Vec::new();
    for _ in 0..count {
        let nl = u16::from_le_bytes(take(2).try_into().unwrap()) as usize;
        let name = String::from_utf8(take(nl).to_vec()).expect("accepted name is UTF-8");
        let code = take(1)[0];
        let len = u64::from_le_bytes(take(8).try_into().unwrap()) as usize;
        let le = |c: &[u8]| u64::from_le_bytes(c.try_into().unwrap());
        let v = match code {
            1 => Values::F32(
                take(4 * len).chunks_exact(4).map(|c| f32::from_le_bytes(c.try_into().unwrap())).collect(),
            ),
            2 => Values::U32(
                take(4 * len).chunks_exact(4).map(|c| u32::from_le_bytes(c.try_into().unwrap())).collect(),
            ),
            3 => Values::U64(take(8 * len).chunks_exact(8).map(le).collect()),
            4 => Values::F64(take(8 * len).chunks_exact(8).map(|c| f64::from_bits(le(c))).collect()),
            5 => Values::Text(String::from_utf8(take(len).to_vec()).expect("accepted text is UTF-8")),
            c => panic!("accepted unknown type {c}"),
        };
        out.push((name, v));
    }
    assert_eq!(pos, body.len(), "accepted trailing bytes");
    out
}

fn same_f32(a: &[f32], b: &[f32]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())
}

fn same_f64(a: &[f64], b: &[f64]) -> bool {
    a.len() == b.len() && a.iter().zip(b).all(|(x, y)| x.to_bits() == y.to_bits())
}

/// Every getter on `name`: the one of its type gives `v`, the others are errors.
fn check_entry(a: &Archive, name: &str, v: &Values) {
    assert!(a.has(name));
    match v {
        Values::F32(v) => assert!(same_f32(a.f32(name).unwrap(), v)),
        _ => assert!(a.f32(name).is_err()),
    }
    match v {
        Values::U32(v) => assert_eq!(a.u32(name).unwrap(), &v[..]),
        _ => assert!(a.u32(name).is_err()),
    }
    match v {
        Values::U64(v) => {
            assert_eq!(a.u64(name).unwrap(), &v[..]);
            assert_eq!(a.scalar(name).ok(), (v.len() == 1).then(|| v[0]));
        }
        _ => assert!(a.u64(name).is_err() && a.scalar(name).is_err()),
    }
    match v {
        Values::F64(v) => assert!(same_f64(a.f64(name).unwrap(), v)),
        _ => assert!(a.f64(name).is_err()),
    }
    match v {
        Values::Text(v) => assert_eq!(a.text(name).unwrap(), v),
        _ => assert!(a.text(name).is_err()),
    }
    if let Values::F32(v) = v {
        assert!(a.f32_len(name, v.len()).is_ok() && a.f32_len(name, v.len() + 1).is_err());
    }
}

/// The invariants for an archive `parse` accepted from `bytes`.
fn check(bytes: &[u8], a: &Archive) {
    let path = Path::new("fuzz.ckpt");
    let entries = walk(&bytes[..bytes.len() - 16]);
    // Names are unique: a repeated name is refused.
    for (i, (name, v)) in entries.iter().enumerate() {
        assert!(!entries[..i].iter().any(|(n, _)| n == name), "accepted a repeated name {name:?}");
        check_entry(a, name, v);
    }
    assert!(!a.has("\u{0}not an entry\u{0}") || entries.iter().any(|(n, _)| n == "\u{0}not an entry\u{0}"));
    let again = written(&entries);
    assert_eq!(again, bytes, "the same entries written again give other bytes");
    let b = Archive::parse(&again, path).expect("a file we wrote reads back");
    assert_eq!(b.checksum(), a.checksum());
    for (name, v) in &entries {
        check_entry(&b, name, v);
    }
}

/// A little byte reader that pads with zeros when the input runs out.
struct Bytes<'a>(&'a [u8]);

impl Bytes<'_> {
    fn take<const N: usize>(&mut self) -> [u8; N] {
        let mut out = [0u8; N];
        let k = N.min(self.0.len());
        out[..k].copy_from_slice(&self.0[..k]);
        self.0 = &self.0[k..];
        out
    }
    fn byte(&mut self) -> u8 {
        self.take::<1>()[0]
    }
}

/// Entries from bytes: per entry a type byte, a name (length byte % 24, then bytes,
/// made UTF-8 lossily), a count byte % 40, then the values' little-endian bytes.
fn build(data: &[u8]) -> Vec<(String, Values)> {
    let mut r = Bytes(data);
    let mut out = Vec::new();
    while !r.0.is_empty() && out.len() < 64 {
        let code = r.byte() % 5;
        let nl = (r.byte() % 24) as usize;
        let name: Vec<u8> = (0..nl).map(|_| r.byte()).collect();
        let name = String::from_utf8_lossy(&name).into_owned();
        let n = (r.byte() % 40) as usize;
        let v = match code {
            0 => Values::F32((0..n).map(|_| f32::from_le_bytes(r.take())).collect()),
            1 => Values::U32((0..n).map(|_| u32::from_le_bytes(r.take())).collect()),
            2 => Values::U64((0..n).map(|_| u64::from_le_bytes(r.take())).collect()),
            3 => Values::F64((0..n).map(|_| f64::from_le_bytes(r.take())).collect()),
            _ => Values::Text(
                String::from_utf8_lossy(&(0..n).map(|_| r.byte()).collect::<Vec<_>>()).into_owned(),
            ),
        };
        // A repeated name is refused by the reader: keep the first.
        if !out.iter().any(|(n, _)| *n == name) {
            out.push((name, v));
        }
    }
    out
}

fn written(entries: &[(String, Values)]) -> Vec<u8> {
    let mut w = Writer::new();
    for (name, v) in entries {
        match v {
            Values::F32(v) => w.f32(name.as_str(), &v[..]),
            Values::U32(v) => w.u32(name.as_str(), &v[..]),
            Values::U64(v) => w.u64(name.as_str(), &v[..]),
            Values::F64(v) => w.f64(name.as_str(), &v[..]),
            Values::Text(v) => w.text(name.as_str(), v.as_str()),
        };
    }
    w.to_bytes()
}

fuzz_target!(|data: &[u8]| {
    let path = Path::new("fuzz.ckpt");
    let Some((&mode, rest)) = data.split_first() else { return };
    match mode % 4 {
        0 => {
            if let Ok(a) = Archive::parse(rest, path) {
                check(rest, &a);
            }
        }
        1 => {
            let bytes = with_trailer(rest);
            if let Ok(a) = Archive::parse(&bytes, path) {
                check(&bytes, &a);
            }
        }
        2 => {
            let entries = build(rest);
            let bytes = written(&entries);
            let n = bytes.len();
            assert_eq!(
                checksum(&bytes[..n - 16]).to_le_bytes(),
                bytes[n - 16..n - 8],
                "fuzz/fuzz_targets/archive.rs: the checksum re-implementation no longer matches the writer"
            );
            let a = Archive::parse(&bytes, path).expect("a file Writer wrote reads back");
            check(&bytes, &a);
        }
        _ => {
            let [o0, o1, k, x] = Bytes(rest).take::<4>();
            let bytes = written(&build(rest.get(4..).unwrap_or_default()));
            let mut body = bytes[..bytes.len() - 16].to_vec();
            let at = u16::from_le_bytes([o0, o1]) as usize % body.len();
            match k % 4 {
                // cut the body here
                0 => body.truncate(at),
                // drop k/4 bytes here
                1 => drop(body.drain(at..(at + (k / 4) as usize).min(body.len()))),
                // insert k/4 copies of x here
                2 => drop(body.splice(at..at, std::iter::repeat(x).take((k / 4) as usize))),
                // xor x into up to k/4 + 1 bytes from here
                _ => body[at..].iter_mut().take((k / 4) as usize + 1).for_each(|b| *b ^= x),
            }
            let bytes = with_trailer(&body);
            if let Ok(a) = Archive::parse(&bytes, path) {
                check(&bytes, &a);
            }
        }
    }
});
