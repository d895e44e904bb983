//! The lean encoding of triangle groups (format-spec §7.3): a chunk of a lean block
//! ([`super::format::CODEC_LEAN`]) stores each 160-byte [`TriGroup`] as only what it holds:
//! the corner slots its lanes use, its lanes' corner slots in 3 bits each and its primitive ids
//! as offsets from the smallest. Lossless: a group decodes to the same 160 bytes, so the
//! tracer's answers are the mesh's bit for bit; about 0.65 of the raw bytes on the dragon
//! (5.1 lanes and 6.9 corners a group; ids within 65,535 of each other in 99.99 % of groups).
//!
//! Written by hand because it is the format: no crate knows our groups. Decoding is a few
//! shifts and copies a group, far cheaper than zstd, so a lean file is read at about raw speed
//! for fewer bytes from the disk.

use bytemuck::Zeroable;

use super::format::{GROUP_CORNERS, GROUP_LANES, TriGroup};

/// Bytes a group takes at most once encoded: 1 + 96 + 9 + 4 + 32 (less than 160).
pub const MAX_LEAN_GROUP: usize = 1 + 12 * GROUP_CORNERS + 9 + 4 + 4 * GROUP_LANES;
const _: () = assert!(MAX_LEAN_GROUP < std::mem::size_of::<TriGroup>());

/// Appends the lean encoding of `g` to `out`. `Err` if `g` is not a group as the spec has
/// them (lanes `1..=8`, slots `< 8`, unused lanes, slots and `reserved` zero): such a group
/// would not decode to itself, and is not written.
pub fn encode_group(g: &TriGroup, out: &mut Vec<u8>) -> Result<(), String> {
    let count = g.count as usize;
    if !(1..=GROUP_LANES).contains(&count) {
        return Err(format!("a group of {count} lanes"));
    }
    let corners = (0..3)
        .flat_map(|c| g.tri[c][..count].iter())
        .map(|&s| s as usize + 1)
        .max()
        .unwrap_or(1);
    if corners > GROUP_CORNERS {
        return Err(format!("a corner slot of {}", corners - 1));
    }
    let prims = &g.prim[..count];
    let base = *prims.iter().min().unwrap_or(&0);
    let span = prims.iter().max().unwrap_or(&0) - base;
    let width: usize = match span {
        0..=0xFF => 1,
        0x100..=0xFFFF => 2,
        _ => 4,
    };
    let start = out.len();
    out.push((count - 1) as u8 | ((corners - 1) as u8) << 3 | (width.trailing_zeros() as u8) << 6);
    for row in &g.corner {
        for v in &row[..corners] {
            out.extend_from_slice(&v.to_le_bytes());
        }
    }
    let mut bits = 0u128;
    for l in 0..count {
        for c in 0..3 {
            bits |= ((g.tri[c][l] & 7) as u128) << (3 * (3 * l + c));
        }
    }
    out.extend_from_slice(&bits.to_le_bytes()[..(9 * count).div_ceil(8)]);
    out.extend_from_slice(&base.to_le_bytes());
    for &p in prims {
        out.extend_from_slice(&(p - base).to_le_bytes()[..width]);
    }
    let mut back = TriGroup::zeroed();
    match decode_group(&out[start..], &mut back) {
        Ok(n) if n == out.len() - start && back == *g => Ok(()),
        _ => Err(
            "a group with bytes outside its lanes and slots (it would not decode to \
                  itself)"
                .into(),
        ),
    }
}

/// Decodes one lean group from the start of `bytes` into `g` (every byte of it written);
/// the bytes it took. `Err` on a truncated or malformed encoding (a slot past the corners
/// stored, an unknown width, an id past `u32::MAX`).
#[inline]
pub fn decode_group(bytes: &[u8], g: &mut TriGroup) -> Result<usize, String> {
    let &b0 = bytes.first().ok_or("a group cut short")?;
    let count = (b0 & 7) as usize + 1;
    let corners = (b0 >> 3 & 7) as usize + 1;
    let width = match b0 >> 6 {
        3 => return Err("a group with an unknown id width".into()),
        w => 1usize << w,
    };
    let slot_bytes = (9 * count).div_ceil(8);
    let len = 1 + 12 * corners + slot_bytes + 4 + width * count;
    let b = bytes.get(..len).ok_or("a group cut short")?;
    *g = TriGroup::zeroed();
    let mut at = 1;
    for row in &mut g.corner {
        for v in &mut row[..corners] {
            *v = f32::from_le_bytes(b[at..at + 4].try_into().unwrap_or_default());
            at += 4;
        }
    }
    let mut raw = [0u8; 16];
    raw[..slot_bytes].copy_from_slice(&b[at..at + slot_bytes]);
    at += slot_bytes;
    let bits = u128::from_le_bytes(raw);
    for l in 0..count {
        for c in 0..3 {
            let s = (bits >> (3 * (3 * l + c))) as u8 & 7;
            if s as usize >= corners {
                return Err(format!("lane {l} names corner slot {s} of {corners}"));
            }
            g.tri[c][l] = s;
        }
    }
    let base = u32::from_le_bytes(b[at..at + 4].try_into().unwrap_or_default());
    at += 4;
    g.count = count as u32;
    for p in &mut g.prim[..count] {
        let mut o = [0u8; 4];
        o[..width].copy_from_slice(&b[at..at + width]);
        at += width;
        *p = base
            .checked_add(u32::from_le_bytes(o))
            .ok_or("a primitive id past u32::MAX")?;
    }
    Ok(len)
}

/// The lean encoding of a chunk's raw groups (`raw`: whole groups): each group's, one after
/// another.
pub fn encode_chunk(raw: &[u8]) -> Result<Vec<u8>, String> {
    let size = std::mem::size_of::<TriGroup>();
    if !raw.len().is_multiple_of(size) {
        return Err(format!("{} bytes are not whole groups", raw.len()));
    }
    let mut out = Vec::with_capacity(raw.len() * 3 / 4);
    for (i, g) in raw.chunks_exact(size).enumerate() {
        let g: TriGroup = bytemuck::pod_read_unaligned(g);
        encode_group(&g, &mut out).map_err(|e| format!("group {i}: {e}"))?;
    }
    Ok(out)
}

/// Decodes a lean chunk `stored` into `out`, its raw groups (whole groups): `Err` naming the
/// group if a group is malformed or cut short, or if bytes are left over.
pub fn decode_chunk(stored: &[u8], out: &mut [u8]) -> Result<(), String> {
    let size = std::mem::size_of::<TriGroup>();
    if !out.len().is_multiple_of(size) {
        return Err(format!("{} bytes are not whole groups", out.len()));
    }
    let mut at = 0;
    for (i, dst) in out.chunks_exact_mut(size).enumerate() {
        let mut g = TriGroup::zeroed();
        at += decode_group(&stored[at..], &mut g)
            .map_err(|e| format!("lean group {i} (byte {at}): {e}"))?;
        dst.copy_from_slice(bytemuck::bytes_of(&g));
    }
    if at != stored.len() {
        return Err(format!(
            "{} bytes left after its {} lean groups",
            stored.len() - at,
            out.len() / size
        ));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Groups of every shape: 1 to 8 lanes, 1 to 8 corners (lane 7's slots cross the 64th
    /// bit), ids 1, 2 and 4 bytes apart, the largest id, negative and odd coordinates.
    fn groups() -> Vec<TriGroup> {
        let mut out = Vec::new();
        let mut seed = 0x9E37_79B9_7F4A_7C15u64;
        let mut next = || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            seed
        };
        for count in 1..=8usize {
            for corners in 1..=8usize {
                for span in [0u32, 200, 60_000, 3_000_000_000] {
                    let mut g = TriGroup::zeroed();
                    g.count = count as u32;
                    for k in 0..3 {
                        for j in 0..corners {
                            g.corner[k][j] = f32::from_bits(next() as u32 & 0x7F7F_FFFF)
                                * if next() & 1 == 0 { -1.0 } else { 1.0 };
                        }
                    }
                    for l in 0..count {
                        for c in 0..3 {
                            g.tri[c][l] = (next() % corners as u64) as u8;
                        }
                    }
                    // The highest slot used somewhere, so that every corner stored is named.
                    g.tri[2][count - 1] = corners as u8 - 1;
                    let base = u32::MAX - span - (next() % 1000) as u32;
                    for l in 0..count {
                        g.prim[l] = base + (next() % (span as u64 + 1)) as u32;
                    }
                    g.prim[0] = base;
                    out.push(g);
                }
            }
        }
        out
    }

    #[test]
    fn every_group_decodes_to_itself_and_takes_fewer_bytes() {
        let gs = groups();
        let mut raw = Vec::new();
        for g in &gs {
            let mut one = Vec::new();
            encode_group(g, &mut one).unwrap();
            assert!(one.len() <= MAX_LEAN_GROUP, "{} bytes", one.len());
            let mut back = TriGroup::zeroed();
            assert_eq!(decode_group(&one, &mut back), Ok(one.len()));
            assert_eq!(back, *g);
            raw.extend_from_slice(bytemuck::bytes_of(g));
        }
        let lean = encode_chunk(&raw).unwrap();
        assert!(
            lean.len() < raw.len() * 3 / 4,
            "{} of {}",
            lean.len(),
            raw.len()
        );
        let mut out = vec![0xAAu8; raw.len()];
        decode_chunk(&lean, &mut out).unwrap();
        assert!(out == raw);
    }

    /// A group with bytes the encoding does not keep (an unused slot's corner, a lane past the
    /// count, `reserved`) is refused rather than written changed.
    #[test]
    fn a_group_that_would_not_decode_to_itself_is_refused() {
        let g = groups()[40];
        for spoil in [
            |g: &mut TriGroup| g.corner[1][7] = 1.0,
            |g: &mut TriGroup| g.reserved = 1,
            |g: &mut TriGroup| g.prim[7] = 5,
            |g: &mut TriGroup| g.tri[0][0] = 9,
            |g: &mut TriGroup| g.count = 0,
            |g: &mut TriGroup| g.count = 9,
        ] {
            let mut bad = g;
            bad.count = 3;
            bad.tri = [[0; 8]; 3];
            bad.prim[3..].fill(0);
            for k in 0..3 {
                bad.corner[k][1..].fill(0.0);
            }
            let mut out = Vec::new();
            assert!(encode_group(&bad, &mut out).is_ok());
            spoil(&mut bad);
            assert!(encode_group(&bad, &mut Vec::new()).is_err(), "{bad:?}");
        }
    }

    /// Malformed bytes fail with what is wrong, never a panic: cut short anywhere, an unknown
    /// width, a slot past the corners, an id past `u32::MAX`, bytes left over.
    #[test]
    fn malformed_lean_bytes_are_errors() {
        let gs = groups();
        let mut raw = Vec::new();
        for g in &gs[..20] {
            raw.extend_from_slice(bytemuck::bytes_of(g));
        }
        let lean = encode_chunk(&raw).unwrap();
        let mut out = vec![0u8; raw.len()];
        for cut in 0..lean.len() {
            assert!(
                decode_chunk(&lean[..cut], &mut out).is_err(),
                "cut at {cut}"
            );
        }
        let mut longer = lean.clone();
        longer.push(0);
        assert!(
            decode_chunk(&longer, &mut out)
                .unwrap_err()
                .contains("left")
        );
        // Byte 0 of the first group: width 3.
        let mut bad = lean.clone();
        bad[0] |= 0xC0;
        assert!(decode_chunk(&bad, &mut out).unwrap_err().contains("width"));
        // One lane, one corner, slot 7 named.
        let one = [
            0u8, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0b111, 0, 0, 0, 0, 0, 0,
        ];
        let e = decode_group(&one, &mut TriGroup::zeroed()).unwrap_err();
        assert!(e.contains("slot"), "{e}");
        // Two lanes of 1-byte ids from u32::MAX - 1: the second 2 past it.
        let mut over = vec![1u8];
        over.extend_from_slice(&[0; 12]);
        over.extend_from_slice(&[0, 0, 0]);
        over.extend_from_slice(&(u32::MAX - 1).to_le_bytes());
        over.extend_from_slice(&[0, 3]);
        let e = decode_group(&over, &mut TriGroup::zeroed()).unwrap_err();
        assert!(e.contains("u32::MAX"), "{e}");
    }
}
