//! Ray, hit and occlusion files (`../shared/RAYS.md`).
//!
//! All three files are a 16-byte header (4-byte magic, `u32` version 1, `u64` count) followed by
//! `count` records; the size must be exactly `16 + count * record_size`. Records are cast from
//! and to [`Ray`] and [`Hit`], whose layout is the record layout. Reading checks the header
//! before the body, so a file is never read (or allocated for) beyond what it says it holds,
//! nor beyond the caller's limit.

use std::path::Path;

use bytemuck::Pod;

use crate::error::Error;
use crate::geom::{AllHits, Hit, ListedHit, Ray};

use crate::output::Output;

const VERSION: u32 = 1;
const HEADER: usize = 16;

/// Reads a batch file of at most `max_records` records: the header is read first, and a file
/// that claims more records than that, or whose size is not what its header says, is refused
/// before its body is read.
fn read_records<T: Pod>(path: &Path, magic: &[u8; 4], max_records: u64) -> Result<Vec<T>, Error> {
    use std::io::Read;
    let invalid = |what: String| Error::Invalid(format!("{}: {what}", path.display()));
    let mut file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
    let len = file.metadata().map_err(|e| Error::io(path, e))?.len();
    let mut head = [0u8; HEADER];
    let got = file.read(&mut head).map_err(|e| Error::io(path, e))?;
    let count =
        header_count(&head[..got], magic, len, std::mem::size_of::<T>()).map_err(invalid)?;
    if count > max_records {
        return Err(invalid(format!(
            "{count} records, more than the {max_records} this run can hold in memory"
        )));
    }
    let mut bytes = Vec::new();
    bytes
        .try_reserve_exact(len as usize)
        .map_err(|_| invalid(format!("cannot allocate {len} bytes to read it")))?;
    bytes.extend_from_slice(&head[..got]);
    // `take`: a file that grows while it is read cannot make us read more than it said.
    file.take(len - got as u64)
        .read_to_end(&mut bytes)
        .map_err(|e| Error::io(path, e))?;
    parse_records(&bytes, magic).map_err(invalid)
}

/// The record count of a batch file whose first bytes are `head` and whose size is `len`,
/// checked against the header (magic, version, `16 + count * size == len`).
fn header_count(head: &[u8], magic: &[u8; 4], len: u64, size: usize) -> Result<u64, String> {
    let name = String::from_utf8_lossy(magic);
    if head.len() < HEADER {
        return Err(format!("{len} bytes: too short for a {name} file header"));
    }
    if &head[..4] != magic {
        return Err(format!(
            "magic {:?}, expected {name:?}",
            String::from_utf8_lossy(&head[..4])
        ));
    }
    let version = u32::from_le_bytes(head[4..8].try_into().unwrap_or_default());
    if version != VERSION {
        return Err(format!(
            "{name} version {version}, this oavm reads version {VERSION}"
        ));
    }
    let count = u64::from_le_bytes(head[8..16].try_into().unwrap_or_default());
    let expected = count
        .checked_mul(size as u64)
        .and_then(|n| n.checked_add(HEADER as u64));
    if expected != Some(len) {
        return Err(format!(
            "header says {count} records of {size} bytes, but the file has {len} bytes (expected {})",
            expected.map_or("more than 2^64".to_string(), |e| e.to_string())
        ));
    }
    Ok(count)
}

/// Parses a batch file held in memory; the error says what is wrong (the caller names the file).
pub fn parse_records<T: Pod>(bytes: &[u8], magic: &[u8; 4]) -> Result<Vec<T>, String> {
    let size = std::mem::size_of::<T>();
    header_count(bytes, magic, bytes.len() as u64, size)?;
    // Copy out: the Vec<u8> read from disk has no alignment guarantee for T.
    Ok(bytes[HEADER..]
        .chunks_exact(size)
        .map(bytemuck::pod_read_unaligned)
        .collect())
}

/// The bytes of a batch file holding `records`.
pub fn encode_records<T: Pod>(records: &[T], magic: &[u8; 4]) -> Vec<u8> {
    let body: &[u8] = bytemuck::cast_slice(records);
    let mut out = Vec::with_capacity(HEADER + body.len());
    out.extend_from_slice(magic);
    out.extend_from_slice(&VERSION.to_le_bytes());
    out.extend_from_slice(&(records.len() as u64).to_le_bytes());
    out.extend_from_slice(body);
    out
}

/// A record of a batch file: a ray, a closest hit, or an any-hit answer (one byte).
pub trait Record: Pod {
    /// The file's magic.
    const MAGIC: &'static [u8; 4];
}

impl Record for Ray {
    const MAGIC: &'static [u8; 4] = b"RAYS";
}

impl Record for Hit {
    const MAGIC: &'static [u8; 4] = b"HITS";
}

impl Record for u8 {
    const MAGIC: &'static [u8; 4] = b"OCCL";
}

/// Hit counts (`--count-hits`): one `u32` per ray, how many triangles it hits
/// ([`crate::Scene::count_intersections`]).
impl Record for u32 {
    const MAGIC: &'static [u8; 4] = b"HITC";
}

/// The magic of a hit-list file (`docs/cli.md`, "Every hit"): the header's count is the
/// number of rays; then one `u32` per ray (its number of hits), then every ray's hits end to
/// end as 16-byte [`ListedHit`] records, ray by ray, each ray's in order of `t`.
pub const HIT_LISTS_MAGIC: &[u8; 4] = b"HITL";

/// The bytes of a hit-list file holding `all`.
pub fn encode_hit_lists(all: &AllHits) -> Vec<u8> {
    let mut out = encode_records(&all.counts(), HIT_LISTS_MAGIC);
    out.extend_from_slice(bytemuck::cast_slice(&all.hits));
    out
}

/// Parses a hit-list file held in memory: its size must be exactly the header, the counts and
/// as many records as they add up to.
pub fn parse_hit_lists(bytes: &[u8]) -> Result<AllHits, String> {
    let name = "HITL";
    let head = bytes
        .get(..HEADER)
        .ok_or_else(|| format!("{} bytes: too short for a {name} file header", bytes.len()))?;
    let rays = u64::from_le_bytes(head[8..16].try_into().unwrap_or_default());
    let counts_end = rays
        .checked_mul(4)
        .and_then(|n| n.checked_add(HEADER as u64));
    let counts_end = counts_end
        .filter(|&e| e <= bytes.len() as u64)
        .ok_or_else(|| {
            format!(
                "header says {rays} rays, more counts than the file's {} bytes hold",
                bytes.len()
            )
        })?;
    let counts: Vec<u32> = parse_records(&bytes[..counts_end as usize], HIT_LISTS_MAGIC)?;
    let total: u64 = counts.iter().map(|&c| c as u64).sum();
    let size = std::mem::size_of::<ListedHit>() as u64;
    let expected = total
        .checked_mul(size)
        .and_then(|n| n.checked_add(counts_end));
    if expected != Some(bytes.len() as u64) {
        return Err(format!(
            "its counts add up to {total} hits of {size} bytes after {counts_end} bytes, \
             but the file has {} bytes",
            bytes.len()
        ));
    }
    let hits = bytes[counts_end as usize..]
        .chunks_exact(size as usize)
        .map(bytemuck::pod_read_unaligned)
        .collect();
    let mut splits = Vec::with_capacity(counts.len() + 1);
    splits.push(0);
    for c in counts {
        splits.push(splits[splits.len() - 1] + c as u64);
    }
    Ok(AllHits { splits, hits })
}

/// Writes `all` as a hit-list file into `out` and commits it.
pub fn write_hit_lists(mut out: Output, all: &AllHits) -> Result<(), Error> {
    use std::io::Write;
    let path = out.path().to_owned();
    out.file()
        .write_all(&encode_hit_lists(all))
        .map_err(|e| Error::io(path, e))?;
    out.commit()
}

/// Reads a hit-list file of at most `max_bytes` bytes.
pub fn read_hit_lists(path: &Path, max_bytes: u64) -> Result<AllHits, Error> {
    let invalid = |what: String| Error::Invalid(format!("{}: {what}", path.display()));
    let len = std::fs::metadata(path)
        .map_err(|e| Error::io(path, e))?
        .len();
    if len > max_bytes {
        return Err(invalid(format!(
            "{len} bytes, more than the {max_bytes} this run can hold in memory"
        )));
    }
    let bytes = std::fs::read(path).map_err(|e| Error::io(path, e))?;
    parse_hit_lists(&bytes).map_err(invalid)
}

/// Writes `records` as a batch file into `out` (created, and so checked, before the work: see
/// [`crate::output`]) and commits it.
pub fn write_into<T: Record>(mut out: Output, records: &[T]) -> Result<(), Error> {
    use std::io::Write;
    let bytes = encode_records(records, T::MAGIC);
    let path = out.path().to_owned();
    out.file()
        .write_all(&bytes)
        .map_err(|e| Error::io(path, e))?;
    out.commit()
}

/// Writes `records` as a batch file at `path` (atomically, see [`crate::output`]).
pub fn write<T: Record>(path: &Path, records: &[T]) -> Result<(), Error> {
    write_into(Output::create(path, &[])?, records)
}

/// Reads a batch file of at most `max` records.
pub fn read<T: Record>(path: &Path, max: u64) -> Result<Vec<T>, Error> {
    read_records(path, T::MAGIC, max)
}

/// Reads a RAYS file of at most `max_rays` rays.
pub fn read_rays(path: &Path, max_rays: u64) -> Result<Vec<Ray>, Error> {
    read(path, max_rays)
}

/// Writes a RAYS file.
pub fn write_rays(path: &Path, rays: &[Ray]) -> Result<(), Error> {
    write(path, rays)
}

/// Reads a HITS file of at most `max` records.
pub fn read_hits(path: &Path, max: u64) -> Result<Vec<Hit>, Error> {
    read(path, max)
}

/// Writes a HITS file.
pub fn write_hits(path: &Path, hits: &[Hit]) -> Result<(), Error> {
    write(path, hits)
}

/// Reads an OCCL file of at most `max` records.
pub fn read_occlusion(path: &Path, max: u64) -> Result<Vec<u8>, Error> {
    read(path, max)
}

/// Writes an OCCL file.
pub fn write_occlusion(path: &Path, occluded: &[u8]) -> Result<(), Error> {
    write(path, occluded)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn batch_files_round_trip_and_reject_bad_sizes() {
        let rays = vec![Ray::new(
            [1.0, 2.0, 3.0],
            [0.0, 0.0, 1.0],
            0.5,
            f32::INFINITY,
        )];
        let bytes = encode_records(&rays, b"RAYS");
        assert_eq!(bytes.len(), 16 + 32);
        assert_eq!(parse_records::<Ray>(&bytes, b"RAYS").unwrap(), rays);
        assert!(
            parse_records::<Ray>(&bytes[..47], b"RAYS")
                .unwrap_err()
                .contains("header says 1")
        );
        assert!(
            parse_records::<Ray>(&bytes, b"HITS")
                .unwrap_err()
                .contains("magic")
        );
        let mut v2 = bytes.clone();
        v2[4] = 2;
        assert!(
            parse_records::<Ray>(&v2, b"RAYS")
                .unwrap_err()
                .contains("version 2")
        );
        let mut huge = bytes.clone();
        huge[8..16].copy_from_slice(&u64::MAX.to_le_bytes());
        assert!(parse_records::<Ray>(&huge, b"RAYS").is_err());
    }

    #[test]
    fn reading_refuses_files_beyond_the_limit_before_their_body() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("r.rays");
        let rays = vec![Ray::new([0.0; 3], [1.0, 0.0, 0.0], 0.0, 1.0); 10];
        std::fs::write(&p, encode_records(&rays, b"RAYS")).unwrap();
        assert_eq!(read_rays(&p, 10).unwrap(), rays);
        let e = read_rays(&p, 9).unwrap_err().to_string();
        assert!(e.contains("10 records, more than the 9"), "{e}");
        // A header claiming far more than the file holds is refused without reading.
        let mut huge = encode_records(&rays, b"RAYS");
        huge[8..16].copy_from_slice(&(1u64 << 40).to_le_bytes());
        std::fs::write(&p, huge).unwrap();
        let e = read_rays(&p, u64::MAX).unwrap_err().to_string();
        assert!(e.contains("header says 1099511627776"), "{e}");
    }
}
