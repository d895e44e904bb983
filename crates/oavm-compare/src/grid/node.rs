//! The grid's storage: every cell's list of triangle indices, laid out CSR (compressed sparse
//! rows), cells numbered x fastest, then y, then z.

/// The triangle lists of all cells: `offsets[c]..offsets[c + 1]` is cell `c`'s range of `refs`.
#[derive(Clone, Debug)]
pub(super) struct Cells {
    offsets: Vec<u32>,
    /// Triangle indices (into the grid's soup) of all cells, cell after cell.
    refs: Vec<u32>,
}

impl Default for Cells {
    /// No cells.
    fn default() -> Cells {
        Cells {
            offsets: vec![0],
            refs: Vec::new(),
        }
    }
}

impl Cells {
    /// `offsets` has one entry per cell and a closing one (`refs.len()`), and never decreases.
    pub(super) fn new(offsets: Vec<u32>, refs: Vec<u32>) -> Cells {
        debug_assert!(offsets.last().is_some_and(|&e| e as usize == refs.len()));
        Cells { offsets, refs }
    }

    /// Number of cells.
    pub(super) fn count(&self) -> usize {
        self.offsets.len().saturating_sub(1)
    }

    pub(super) fn references(&self) -> usize {
        self.refs.len()
    }

    /// Bytes of the offsets and the references.
    pub(super) fn bytes(&self) -> usize {
        4 * self.offsets.len() + 4 * self.refs.len()
    }

    /// The triangles of cell `c` (empty for a cell that does not exist).
    #[inline]
    pub(super) fn list(&self, c: usize) -> &[u32] {
        match (self.offsets.get(c), self.offsets.get(c + 1)) {
            (Some(&a), Some(&b)) => self.refs.get(a as usize..b as usize).unwrap_or(&[]),
            _ => &[],
        }
    }
}
