//! The encoder's reconstruction field: one integer height per lattice point of the domain.
//!
//! With α = 1 a refinement never changes the vertices it starts from; it only adds the values at
//! the cell centres of its square, which are the lattice points new at the next level. So the
//! reconstructed value of a lattice point is fixed at the level where it first appears, and one
//! array over the domain holds every level's reconstruction at once. Level `l`'s refinements
//! write their new points into it, and level `l+1` gathers its grids from it by lattice index.
//! This replaces a map of every previous-level diamond's `(2N−1)²` half-step grid (16 bytes and
//! more per input sample at the fine levels) by 4 bytes per lattice point.
//!
//! Disjointness, which makes the parallel writes race-free: the cell centres of a level tile the
//! domain — each new point is strictly inside exactly one diamond of the level (diamonds of a
//! level tile the plane, cell centres are interior to their diamond) — and every point a level
//! reads is older than that level. Points outside the domain (the mirrored halves of diamonds on
//! its edge) are never stored: no child of an edge diamond reads them, since every child's half
//! in a parent lies inside the domain; the gather rebuilds them by the same mirroring as
//! [`super::gather`].
//!
//! The field lives in anonymous memory or in a memory-mapped unlinked temporary file
//! ([`TempStorage`]); either way its pages are zero until touched, so parts of the domain no
//! stored diamond reaches cost nothing.

use std::ptr::NonNull;
use std::sync::atomic::{AtomicI32, Ordering};

use memmap2::MmapMut;

use super::refine::{half_range, mirror_missing_halves};
use crate::CodecError;
use crate::geometry::{DiamondId, Domain, Half};
pub use crate::temp::TempStorage;

/// Integer heights over the lattice points `[0, width) × [0, height)`, shared by the workers of
/// one level. Accesses are relaxed atomics: plain loads and stores on every platform that
/// matters, and safe without proof that no two workers touch one point; the order between
/// levels comes from rayon's join at the end of each level.
pub(crate) struct ReconField {
    /// Lattice point of index 0.
    origin: (i64, i64),
    /// Lattice units between neighbouring points of the field, `2^shift`: 1 for the whole
    /// lattice, coarser for a field that holds only the points of the coarse levels.
    shift: u32,
    width: usize,
    height: usize,
    ptr: NonNull<AtomicI32>,
    /// Owns the memory `ptr` points into; never accessed as bytes.
    _map: MmapMut,
}

// SAFETY: `ptr` points into `_map`, which the field owns and which lives exactly as long; every
// access goes through `AtomicI32`, which is `Sync`.
unsafe impl Send for ReconField {}
// SAFETY: as above.
unsafe impl Sync for ReconField {}

impl ReconField {
    /// A zeroed field of `width × height` points in `storage`.
    pub(crate) fn new(
        width: usize,
        height: usize,
        storage: &TempStorage,
    ) -> Result<Self, CodecError> {
        Self::window((0, 0), 0, width, height, storage)
    }

    /// A field over the `width × height` lattice points `origin + 2^shift · (i, j)`: a block
    /// of the domain, or the coarse levels' points only.
    pub(crate) fn window(
        origin: (i64, i64),
        shift: u32,
        width: usize,
        height: usize,
        storage: &TempStorage,
    ) -> Result<Self, CodecError> {
        let too_big = || CodecError::limit("reconstruction field too large for the address space");
        let bytes = width
            .checked_mul(height)
            .and_then(|c| c.checked_mul(4))
            .ok_or_else(too_big)?;
        // A field is never kept: unlinked, in the storage's directory.
        let what = "the reconstruction field";
        let mut map = match storage.unlinked_file(what)? {
            None => MmapMut::map_anon(bytes.max(1))?,
            Some(file) => {
                // Every block on disk before the mapping is written: a full disk is an error
                // here, not a `SIGBUS` at the first page that finds no room.
                let dir = storage.dir().expect("a file storage has a directory");
                crate::temp::reserve(&file, bytes.max(1) as u64, what, &dir, None)?;
                // SAFETY: the file is unlinked and private to this process, so nothing else can
                // truncate or modify it while it is mapped.
                unsafe { MmapMut::map_mut(&file)? }
            }
        };
        // Page-aligned, so aligned for `AtomicI32`; `AtomicI32` has the layout of `i32`, and
        // every bit pattern (zero pages included) is a valid value.
        let ptr = NonNull::new(map.as_mut_ptr().cast::<AtomicI32>()).expect("mmap is non-null");
        Ok(Self {
            origin,
            shift,
            width,
            height,
            ptr,
            _map: map,
        })
    }

    fn cells(&self) -> &[AtomicI32] {
        // SAFETY: the mapping holds at least `width·height` aligned `AtomicI32`s (see `new`) and
        // outlives `self`; all mutation goes through the atomics.
        unsafe { std::slice::from_raw_parts(self.ptr.as_ptr(), self.width * self.height) }
    }

    /// Row-major index of lattice point `(x, y)`, which must lie in the field.
    #[inline]
    fn index(&self, x: i64, y: i64) -> usize {
        debug_assert!(self.contains(x, y), "({x}, {y}) outside the field");
        ((y - self.origin.1) >> self.shift) as usize * self.width
            + ((x - self.origin.0) >> self.shift) as usize
    }

    /// Whether lattice point `(x, y)` is one of the field's.
    #[inline]
    pub(crate) fn contains(&self, x: i64, y: i64) -> bool {
        let (dx, dy) = (x - self.origin.0, y - self.origin.1);
        let mask = (1i64 << self.shift) - 1;
        dx >= 0
            && dy >= 0
            && dx & mask == 0
            && dy & mask == 0
            && ((dx >> self.shift) as usize) < self.width
            && ((dy >> self.shift) as usize) < self.height
    }

    /// The value at lattice point `(x, y)`, one of the field's.
    #[inline]
    pub(crate) fn get(&self, x: i64, y: i64) -> i32 {
        self.cells()[self.index(x, y)].load(Ordering::Relaxed)
    }

    #[inline]
    pub(crate) fn set(&self, x: i64, y: i64, v: i32) {
        self.cells()[self.index(x, y)].store(v, Ordering::Relaxed);
    }

    /// Every value, row-major.
    pub(crate) fn to_vec(&self) -> Vec<i32> {
        self.cells()
            .iter()
            .map(|c| c.load(Ordering::Relaxed))
            .collect()
    }

    /// Sets every value from `values` (row-major, as [`ReconField::to_vec`] gives them).
    pub(crate) fn fill_from(&self, values: &[i32]) -> Result<(), CodecError> {
        let cells = self.cells();
        if values.len() != cells.len() {
            return Err(CodecError::invalid(format!(
                "a field of {} × {} points cannot take {} values",
                self.width,
                self.height,
                values.len()
            )));
        }
        for (c, &v) in cells.iter().zip(values) {
            c.store(v, Ordering::Relaxed);
        }
        Ok(())
    }

    /// Gathers the `N × N` grid of diamond `id`, like [`super::gather`] from its parents'
    /// refinements: the halves whose parent exists are read from the field, a half whose parent
    /// does not exist (a diamond on the domain's edge) is the mirror image of the other across
    /// the split diagonal.
    pub(crate) fn gather(&self, domain: &Domain, id: DiamondId, out: &mut [i32]) {
        let layout = domain.layout();
        let n = layout.n();
        assert_eq!(out.len(), n * n);
        let cells = self.cells();
        let grid = layout.grid(id);
        let diag = layout.diagonal(id);
        let parents = domain.parents(id);
        assert!(
            parents.iter().any(Option::is_some),
            "{id} has no parent to gather from"
        );
        // Moving one step in i is a fixed step in the row-major index (u has no negative part).
        debug_assert!(
            grid.u.0 % (1 << self.shift) == 0 && grid.u.1 % (1 << self.shift) == 0,
            "{id}'s grid is finer than the field"
        );
        let stride =
            (grid.u.1 >> self.shift) as usize * self.width + (grid.u.0 >> self.shift) as usize;
        for (h, half) in Half::BOTH.into_iter().enumerate() {
            if parents[h].is_none() {
                continue;
            }
            for j in 0..n {
                let (lo, hi) = half_range(diag, half, n, j);
                let (x, y) = grid.point(lo as i64, j as i64);
                let (xe, ye) = grid.point(hi as i64, j as i64);
                // Both ends in the field means the whole (straight) row is.
                debug_assert!(self.contains(xe, ye), "{id} reads ({xe}, {ye})");
                let mut k = self.index(x, y);
                for o in &mut out[j * n + lo..=j * n + hi] {
                    *o = cells[k].load(Ordering::Relaxed);
                    k += stride;
                }
            }
        }
        mirror_missing_halves(diag, n, parents.map(|p| p.is_some()), out);
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn both_storages_start_at_zero_and_keep_what_is_stored() {
        for storage in [TempStorage::Memory, TempStorage::File(None)] {
            let f = ReconField::new(7, 5, &storage).unwrap();
            assert!(f.cells().iter().all(|c| c.load(Ordering::Relaxed) == 0));
            f.set(6, 4, -12345);
            f.set(0, 0, 77);
            assert_eq!(f.cells()[34].load(Ordering::Relaxed), -12345);
            assert_eq!(f.cells()[0].load(Ordering::Relaxed), 77);
            assert!(f.contains(6, 4) && !f.contains(7, 0) && !f.contains(0, -1));
        }
    }

    #[test]
    fn an_unusable_temporary_directory_is_an_error_not_a_panic() {
        let missing = std::env::temp_dir().join("cbdam-no-such-dir/sub");
        assert!(ReconField::new(4, 4, &TempStorage::File(Some(missing))).is_err());
    }
}
