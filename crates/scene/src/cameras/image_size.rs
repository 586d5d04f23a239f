//! Image dimensions from a PNG or JPEG header, without decoding the image.

use crate::{Error, Result};
use std::io::Read;
use std::path::Path;

/// Width and height of a PNG or JPEG file.
pub fn read(path: &Path) -> Result<(u32, u32)> {
    // The size is near the start; read a prefix, and the whole file only for a JPEG
    // whose frame header comes after large metadata segments.
    let mut head = Vec::new();
    let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    file.take(1 << 18).read_to_end(&mut head).map_err(|e| Error::io(path, e))?;
    match from_bytes(&head) {
        Ok(wh) => Ok(wh),
        Err(Problem::NeedMore) if head.len() == 1 << 18 => {
            let all = crate::atomic::read(path)?;
            from_bytes(&all).map_err(|p| Error::format(path, p.message()))
        }
        Err(p) => Err(Error::format(path, p.message())),
    }
}

#[derive(Debug, PartialEq)]
pub(crate) enum Problem {
    NotAnImage,
    NeedMore,
    Malformed(&'static str),
}

impl Problem {
    fn message(&self) -> String {
        match self {
            Problem::NotAnImage => "cannot read the image size: not a PNG or JPEG file".into(),
            Problem::NeedMore => {
                "cannot read the image size: the file ends before the JPEG frame header".into()
            }
            Problem::Malformed(m) => format!("cannot read the image size: {m}"),
        }
    }
}

/// Width and height from the start of a PNG or JPEG file.
pub(crate) fn from_bytes(b: &[u8]) -> std::result::Result<(u32, u32), Problem> {
    const PNG: &[u8] = b"\x89PNG\r\n\x1a\n";
    if b.starts_with(PNG) {
        let ihdr = b.get(8..24).ok_or(Problem::NeedMore)?;
        if &ihdr[4..8] != b"IHDR" {
            return Err(Problem::Malformed("PNG without an IHDR chunk first"));
        }
        let be = |o: usize| u32::from_be_bytes([ihdr[o], ihdr[o + 1], ihdr[o + 2], ihdr[o + 3]]);
        return Ok((be(8), be(12)));
    }
    if b.starts_with(&[0xFF, 0xD8]) {
        let mut pos = 2usize;
        loop {
            // Markers may be padded with extra 0xFF bytes.
            while b.get(pos) == Some(&0xFF) && b.get(pos + 1) == Some(&0xFF) {
                pos += 1;
            }
            let (&ff, &marker) =
                (b.get(pos).ok_or(Problem::NeedMore)?, b.get(pos + 1).ok_or(Problem::NeedMore)?);
            if ff != 0xFF {
                return Err(Problem::Malformed("bad JPEG marker"));
            }
            pos += 2;
            match marker {
                0xD8 | 0x01 | 0xD0..=0xD7 => continue,
                0xD9 | 0xDA => return Err(Problem::Malformed("JPEG without a frame header")),
                _ => {}
            }
            let len = b.get(pos..pos + 2).ok_or(Problem::NeedMore)?;
            let len = u16::from_be_bytes([len[0], len[1]]) as usize;
            if len < 2 {
                return Err(Problem::Malformed("bad JPEG segment length"));
            }
            let is_sof = matches!(marker, 0xC0..=0xCF) && !matches!(marker, 0xC4 | 0xC8 | 0xCC);
            if is_sof {
                let s = b.get(pos + 2..pos + 7).ok_or(Problem::NeedMore)?;
                let h = u16::from_be_bytes([s[1], s[2]]) as u32;
                let w = u16::from_be_bytes([s[3], s[4]]) as u32;
                return Ok((w, h));
            }
            pos += len;
        }
    }
    Err(Problem::NotAnImage)
}
