//! Bounded-memory bucket spill: the distribution step of an external sort, for the streaming
//! pack. The builder assigns every triangle to one or more of `N` buckets (cells of the octree),
//! then processes the buckets one at a time; here the triangles wait on disk in between.
//!
//! Every bucket has a buffer in memory; the buffers together hold at most `buffer_bytes` (at
//! least one record per bucket). A full buffer is appended to the spill file as one *run*, and
//! the bucket keeps the list of its runs (offset, count), so that [`SpillBuckets::read`] finds
//! a bucket's records with one positioned read per run, in push order.
//!
//! The spill file is one unnamed temporary file in the given directory
//! ([`tempfile::tempfile_in`]: `O_TMPFILE`, or a file unlinked as soon as it is created): it
//! never has a name in the directory, the kernel frees it when the process ends however it
//! ends (a kill included), and it costs one file descriptor whatever `N` is.

use std::fs::File;
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};

use bytemuck::Zeroable;

use crate::error::Error;
use crate::physical::format::TriRecord;

const RECORD: usize = size_of::<TriRecord>();

/// A bucket's records on disk: `count` records from byte `offset` of the spill file.
#[derive(Clone, Copy, Debug)]
struct Run {
    offset: u64,
    count: u64,
}

#[derive(Debug, Default)]
struct Bucket {
    /// Records not yet written; its capacity is 0 or `SpillBuckets::per_bucket`.
    buffer: Vec<TriRecord>,
    runs: Vec<Run>,
    /// Records in `runs`.
    spilled: u64,
}

/// `N` buckets of [`TriRecord`]s in bounded memory, spilled to an unnamed temporary file. See
/// the module documentation.
#[derive(Debug)]
pub struct SpillBuckets {
    dir: PathBuf,
    file: File,
    buckets: Vec<Bucket>,
    /// Capacity of one bucket's buffer, in records (at least 1).
    per_bucket: usize,
    /// Bytes allocated for buffers now (buffers are allocated at a bucket's first push and
    /// freed by `finish`).
    buffered: usize,
    /// Bytes written to the spill file: where the next run goes.
    disk: u64,
}

impl SpillBuckets {
    /// `buckets` empty buckets whose buffers share `buffer_bytes` (each gets
    /// `buffer_bytes / buckets` bytes, rounded down to whole records, at least one record), with
    /// the spill file in `dir`.
    pub fn new(dir: &Path, buckets: usize, buffer_bytes: usize) -> Result<SpillBuckets, Error> {
        if u32::try_from(buckets).is_err() {
            return Err(Error::Invalid(format!(
                "{buckets} spill buckets: bucket numbers are u32"
            )));
        }
        let file = tempfile::tempfile_in(dir).map_err(|e| {
            Error::io(
                dir,
                std::io::Error::new(
                    e.kind(),
                    format!("cannot create the spill file (an unnamed temporary file) here: {e}"),
                ),
            )
        })?;
        let per_bucket = (buffer_bytes / buckets.max(1) / RECORD).max(1);
        Ok(SpillBuckets {
            dir: dir.to_owned(),
            file,
            buckets: (0..buckets).map(|_| Bucket::default()).collect(),
            per_bucket,
            buffered: 0,
            disk: 0,
        })
    }

    /// Adds `rec` to bucket `bucket`; if that fills its buffer, the buffer is written to the
    /// spill file as a run.
    pub fn push(&mut self, bucket: u32, rec: &TriRecord) -> Result<(), Error> {
        let n = self.buckets.len();
        let Some(b) = self.buckets.get_mut(bucket as usize) else {
            return Err(Error::Invalid(format!(
                "spill bucket {bucket} does not exist (there are {n})"
            )));
        };
        if b.buffer.capacity() == 0 {
            b.buffer.reserve_exact(self.per_bucket);
            self.buffered += b.buffer.capacity() * RECORD;
        }
        b.buffer.push(*rec);
        if b.buffer.len() >= self.per_bucket {
            self.spill(bucket as usize)?;
        }
        Ok(())
    }

    /// Writes every buffer to the spill file and frees the buffers (a later `push` allocates
    /// its bucket's again). Call it once all records are pushed, so that the memory of the
    /// buffers is free while the buckets are read.
    pub fn finish(&mut self) -> Result<(), Error> {
        for i in 0..self.buckets.len() {
            self.spill(i)?;
            let b = &mut self.buckets[i];
            self.buffered -= b.buffer.capacity() * RECORD;
            b.buffer = Vec::new();
        }
        Ok(())
    }

    /// Records pushed to `bucket` (0 for a bucket that does not exist).
    pub fn len(&self, bucket: u32) -> u64 {
        self.buckets
            .get(bucket as usize)
            .map_or(0, |b| b.spilled + b.buffer.len() as u64)
    }

    /// Whether no record was pushed to any bucket.
    #[cfg(test)]
    pub fn is_empty(&self) -> bool {
        self.buckets
            .iter()
            .all(|b| b.spilled == 0 && b.buffer.is_empty())
    }

    /// All the records of `bucket`, in push order: its runs read back from the file, then its
    /// buffer. Exactly `len(bucket)` records, in one allocation.
    pub fn read(&self, bucket: u32) -> Result<Vec<TriRecord>, Error> {
        let Some(b) = self.buckets.get(bucket as usize) else {
            return Err(Error::Invalid(format!(
                "spill bucket {bucket} does not exist (there are {})",
                self.buckets.len()
            )));
        };
        let len = usize::try_from(self.len(bucket))
            .map_err(|_| Error::Invalid(format!("spill bucket {bucket} is too large")))?;
        let mut out = vec![TriRecord::zeroed(); len];
        let mut at = 0usize;
        for run in &b.runs {
            // Each run was written from a buffer, so its count fits in usize.
            let count = run.count as usize;
            let bytes: &mut [u8] = bytemuck::cast_slice_mut(&mut out[at..at + count]);
            self.file.read_exact_at(bytes, run.offset).map_err(|e| {
                self.io_error(
                    e,
                    &format!(
                        "reading {} bytes of bucket {bucket} at offset {}",
                        bytes.len(),
                        run.offset
                    ),
                )
            })?;
            at += count;
        }
        out[at..].copy_from_slice(&b.buffer);
        Ok(out)
    }

    /// Bytes written to the spill file so far.
    pub fn disk_bytes(&self) -> u64 {
        self.disk
    }

    /// Bytes allocated for the buffers now: at most `max(buffer_bytes, buckets * 40)`.
    #[cfg(test)]
    pub fn buffered_bytes(&self) -> usize {
        self.buffered
    }

    /// Writes bucket `i`'s buffer to the end of the spill file as a run, and empties it.
    fn spill(&mut self, i: usize) -> Result<(), Error> {
        let b = &self.buckets[i];
        if b.buffer.is_empty() {
            return Ok(());
        }
        let bytes: &[u8] = bytemuck::cast_slice(&b.buffer);
        let offset = self.disk;
        self.file.write_all_at(bytes, offset).map_err(|e| {
            self.io_error(
                e,
                &format!(
                    "writing {} bytes of bucket {i} at offset {offset}",
                    bytes.len()
                ),
            )
        })?;
        let count = b.buffer.len() as u64;
        self.disk += bytes.len() as u64;
        let b = &mut self.buckets[i];
        b.runs.push(Run { offset, count });
        b.spilled += count;
        b.buffer.clear();
        Ok(())
    }

    /// An I/O error of the spill file, naming its directory.
    fn io_error(&self, e: std::io::Error, what: &str) -> Error {
        Error::io(
            &self.dir,
            std::io::Error::new(e.kind(), format!("spill file: {what}: {e}")),
        )
    }
}

#[cfg(test)]
mod tests;
