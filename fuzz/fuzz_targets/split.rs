//! Splits one fuzz input into a COLMAP model's three files: two little-endian u16
//! lengths (cameras, images), then the bytes of cameras, images and points3D.

pub fn split3(data: &[u8]) -> Option<(&[u8], &[u8], &[u8])> {
    let (head, rest) = (data.get(..4)?, &data[4..]);
    let a = (u16::from_le_bytes([head[0], head[1]]) as usize).min(rest.len());
    let (cams, rest) = rest.split_at(a);
    let b = (u16::from_le_bytes([head[2], head[3]]) as usize).min(rest.len());
    let (images, points) = rest.split_at(b);
    Some((cams, images, points))
}
