//! [`LatticeArray`]: one value per lattice point, in memory or in a mapped file, with the
//! windows, strided copies and page releases the passes over a mapped one need (see the
//! module documentation of [`crate::temp`]).

use std::fmt;
use std::ops::{Deref, DerefMut, Range};
use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};

use memmap2::MmapMut;
#[cfg(unix)]
use memmap2::UncheckedAdvice;

use crate::CodecError;

use super::{
    LATTICE_TEMP_PREFIX, MAPPED_RESIDENT_BYTES, MAPPED_WINDOW_BYTES, TempStorage, creating, reserve,
};

/// Element types a lattice array can hold in a zero-filled mapped file: every one has the
/// all-zero bit pattern as a valid value (0, `false`), and the file is written only through
/// typed slices.
pub trait LatticeElement: Copy + Send + Sync + fmt::Debug + PartialEq + 'static {}
impl LatticeElement for i32 {}
impl LatticeElement for u8 {}
impl LatticeElement for bool {}

/// One value per lattice point, in memory or in a mapped unlinked file (module documentation).
/// Reads and writes go through `Deref`/`DerefMut` to a slice either way.
pub struct LatticeArray<T: LatticeElement> {
    inner: Inner<T>,
}

enum Inner<T> {
    Heap(Vec<T>),
    Mapped {
        map: MmapMut,
        /// The mapped file, read by [`LatticeArray::window`] (on Unix).
        #[cfg_attr(not(unix), allow(dead_code))]
        file: std::fs::File,
        /// Its temporary name ([`TempStorage::Named`]), removed on drop unless persisted.
        name: Option<tempfile::TempPath>,
        len: usize,
        /// Bytes reported read since the resident pages were last dropped.
        touched: AtomicU64,
    },
    /// [`LatticeArray::window`]: an anonymous mapping of `len` elements, allocated (by the
    /// kernel, as pages are first written) only under the window's rows (Unix only; elsewhere
    /// a window is a plain `Vec`).
    #[cfg_attr(not(unix), allow(dead_code))]
    Sparse {
        map: MmapMut,
        len: usize,
    },
}

impl<T: LatticeElement> LatticeArray<T> {
    /// `len` copies of `value` in `storage`.
    pub fn filled(len: usize, value: T, storage: &TempStorage) -> Result<Self, CodecError> {
        let bytes = len
            .checked_mul(size_of::<T>())
            .ok_or_else(|| CodecError::limit("lattice too large for the address space"))?;
        let (file, name) = match storage {
            TempStorage::Memory => {
                return Ok(Self {
                    inner: Inner::Heap(vec![value; len]),
                });
            }
            TempStorage::File(_) => {
                let file = storage.unlinked_file("the lattice")?;
                (file.expect("a file storage makes a file"), None)
            }
            TempStorage::Named(d) => {
                let (file, name) = tempfile::Builder::new()
                    .prefix(LATTICE_TEMP_PREFIX)
                    .tempfile_in(d)
                    .map_err(|e| creating("the lattice", e))?
                    .into_parts();
                (file, Some(name))
            }
        };
        // Every block on disk before the mapping is written: a full disk is an error here,
        // not a `SIGBUS` at the first page that finds no room.
        let dir = storage.dir().expect("a file storage has a directory");
        reserve(
            &file,
            bytes.max(1) as u64,
            "the lattice",
            &dir,
            name.as_deref(),
        )?;
        // SAFETY: the file is unlinked, or has a temporary name nothing else writes, so
        // nothing else truncates or modifies it while it is mapped.
        let map = unsafe { MmapMut::map_mut(&file)? };
        let mut array = Self {
            inner: Inner::Mapped {
                map,
                file,
                name,
                len,
                touched: AtomicU64::new(0),
            },
        };
        // SAFETY: `T`'s all-zero bit pattern is a valid value (see `LatticeElement`).
        let zero: T = unsafe { std::mem::zeroed() };
        if value != zero {
            let window = (MAPPED_WINDOW_BYTES as usize / size_of::<T>()).max(1);
            let mut start = 0;
            while start < len {
                let end = (start + window).min(len);
                array[start..end].fill(value);
                array.release(start..end);
                start = end;
            }
        }
        Ok(array)
    }

    /// Whether the values live in a mapped file.
    pub fn is_mapped(&self) -> bool {
        matches!(self.inner, Inner::Mapped { .. })
    }

    /// Gives the values a lasting file at `path` (replacing any file there), in the host's
    /// byte order: a mapped array of [`TempStorage::Named`] is renamed (no copy; `path` must
    /// be on the same file system, e.g. in the same directory), any other array is written
    /// out under a temporary name and renamed. The array keeps working as before; a later
    /// write to a renamed mapped array changes the file.
    pub fn persist(&mut self, path: &Path) -> Result<(), CodecError> {
        let failed = |e: std::io::Error| {
            CodecError::Io(std::io::Error::new(
                e.kind(),
                format!("writing {}: {e}", path.display()),
            ))
        };
        if let Inner::Mapped { name, .. } = &mut self.inner
            && let Some(temp) = name.take()
        {
            return temp.persist(path).map(|_| ()).map_err(|e| failed(e.error));
        }
        let dir = path.parent().filter(|d| !d.as_os_str().is_empty());
        let mut tmp = tempfile::Builder::new()
            .prefix(LATTICE_TEMP_PREFIX)
            .tempfile_in(dir.unwrap_or(Path::new(".")))
            .map_err(failed)?;
        {
            use std::io::Write;
            let mut out = std::io::BufWriter::with_capacity(1 << 20, tmp.as_file_mut());
            let window = (MAPPED_WINDOW_BYTES as usize / size_of::<T>()).max(1);
            for start in (0..self.len()).step_by(window) {
                let end = (start + window).min(self.len());
                out.write_all(as_bytes(&self[start..end])).map_err(failed)?;
                self.release(start..end);
            }
            out.flush().map_err(failed)?;
        }
        tmp.persist(path).map(|_| ()).map_err(|e| failed(e.error))
    }

    /// The `len` values of `file` (in the host's byte order, as [`LatticeArray::persist`]
    /// writes them), mapped privately: the file is not changed by writes to the array, and
    /// holds memory only where it is read through the mapping. [`LatticeArray::window`] and
    /// [`LatticeArray::strided`] read it without the mapping, and give `false` for any nonzero
    /// byte of a `bool` array that is not 1.
    ///
    /// # Safety
    ///
    /// Every element read through the mapping (`Deref`) must hold a valid `T` in the file (for
    /// `bool`, a byte 0 or 1), and nothing may modify or truncate the file while the array
    /// lives.
    pub unsafe fn map_file(file: std::fs::File, len: usize) -> Result<Self, CodecError> {
        let bytes = len
            .checked_mul(size_of::<T>())
            .ok_or_else(|| CodecError::limit("lattice too large for the address space"))?;
        let found = file.metadata()?.len();
        if found != bytes as u64 {
            return Err(CodecError::Io(std::io::Error::new(
                std::io::ErrorKind::InvalidData,
                format!("a lattice file of {found} bytes where {len} values take {bytes}"),
            )));
        }
        // SAFETY: the caller guarantees that nothing modifies the file while it is mapped.
        let map = if bytes == 0 {
            memmap2::MmapOptions::new().len(1).map_anon()?
        } else {
            unsafe { memmap2::MmapOptions::new().map_copy(&file)? }
        };
        Ok(Self {
            inner: Inner::Mapped {
                map,
                file,
                name: None,
                len,
                touched: AtomicU64::new(0),
            },
        })
    }

    /// Bytes the array keeps resident: all of them in memory, at most
    /// [`MAPPED_RESIDENT_BYTES`] mapped.
    pub fn resident_bytes(&self) -> u64 {
        let bytes = (self.len() * size_of::<T>()) as u64;
        match self.inner {
            Inner::Heap(_) => bytes,
            Inner::Mapped { .. } => bytes.min(MAPPED_RESIDENT_BYTES),
            // Counted by whoever asked for the window ([`LatticeArray::window_bytes`]).
            Inner::Sparse { .. } => 0,
        }
    }

    /// Whether [`LatticeArray::window`] can copy this array: a mapped one, on a system with
    /// anonymous mappings reserved without allocating (Unix) that grants one of its length
    /// (tried: a system that does not overcommit refuses it). The others are read in place.
    pub fn windows(&self) -> bool {
        cfg!(unix) && self.is_mapped() && Self::sparse(self.len()).is_ok()
    }

    /// Bytes a [`LatticeArray::window`] of `rows` rows of `row_len` elements of an array of
    /// rows `width` long takes at most: the whole pages under each row (one more for a row
    /// that straddles two), or under the span of rows where they share pages.
    pub fn window_bytes(rows: usize, row_len: usize, width: usize) -> u64 {
        let (page, size) = (4096, size_of::<T>());
        let by_row = rows * ((row_len * size).div_ceil(page) + 1) * page;
        let span = (rows * width * size).div_ceil(page) * page + page;
        by_row.min(span) as u64
    }

    /// A copy of the rectangle `(x0, y0, x1, y1)` (inclusive, clipped to the array) of this
    /// array, seen as rows of `width` elements, in an array of the same length that holds
    /// nothing else: indexes outside the rectangle read 0 (`false`), and only the rectangle's
    /// rows take memory ([`LatticeArray::window_bytes`]). The rows are read from the file of a
    /// mapped array, without faulting its pages in; others are copied.
    pub fn window(
        &self,
        width: usize,
        (x0, y0, x1, y1): (i64, i64, i64, i64),
    ) -> Result<Self, CodecError> {
        let len = self.len();
        let height = len.checked_div(width).unwrap_or(0);
        let (x0, y0) = (x0.max(0) as usize, y0.max(0) as usize);
        let x1 = (x1.min(width as i64 - 1)).max(-1);
        let y1 = (y1.min(height as i64 - 1)).max(-1);
        let mut out = Self::sparse(len)?;
        if x1 < x0 as i64 || y1 < y0 as i64 {
            return Ok(out);
        }
        let (x1, y1) = (x1 as usize, y1 as usize);
        for y in y0..=y1 {
            let range = y * width + x0..y * width + x1 + 1;
            self.read_into(range.start, &mut out[range])?;
        }
        Ok(out)
    }

    /// The elements at multiples of `2^shift` in both directions of this array, seen as rows
    /// of `width` elements: a compact array in memory of `((width − 1) >> shift) + 1` columns
    /// and `((height − 1) >> shift) + 1` rows. The rows are read from the file of a mapped
    /// array, without faulting its pages in.
    pub fn strided(&self, width: usize, shift: u32) -> Result<Self, CodecError> {
        use rayon::prelude::*;
        let height = self.len().checked_div(width).unwrap_or(0);
        if height == 0 {
            return Ok(Vec::new().into());
        }
        let cw = ((width - 1) >> shift) + 1;
        let ch = ((height - 1) >> shift) + 1;
        // SAFETY: `T`'s all-zero bit pattern is a valid value (see `LatticeElement`).
        let zero: T = unsafe { std::mem::zeroed() };
        let mut out = vec![zero; cw * ch];
        out.par_chunks_mut(cw).enumerate().try_for_each_init(
            || vec![zero; width],
            |row, (j, compact)| {
                let start = (j << shift) * width;
                self.read_into(start, row)?;
                for (i, v) in compact.iter_mut().enumerate() {
                    *v = row[i << shift];
                }
                Ok::<(), CodecError>(())
            },
        )?;
        Ok(out.into())
    }

    /// A copy of the values in `storage`.
    pub fn copied_to(&self, storage: &TempStorage) -> Result<Self, CodecError> {
        // SAFETY: `T`'s all-zero bit pattern is a valid value (see `LatticeElement`).
        let mut out = Self::filled(self.len(), unsafe { std::mem::zeroed() }, storage)?;
        out.copy_from_slice(self);
        Ok(out)
    }

    /// `len` zeros in an anonymous mapping allocated as it is written (Unix), or on the heap.
    fn sparse(len: usize) -> Result<Self, CodecError> {
        #[cfg(unix)]
        {
            let bytes = len
                .checked_mul(size_of::<T>())
                .ok_or_else(|| CodecError::limit("lattice too large for the address space"))?;
            // MAP_NORESERVE: no commitment is charged for the pages never written.
            let map = memmap2::MmapOptions::new()
                .len(bytes.max(1))
                .no_reserve_swap()
                .map_anon()?;
            Ok(Self {
                inner: Inner::Sparse { map, len },
            })
        }
        #[cfg(not(unix))]
        {
            // SAFETY: `T`'s all-zero bit pattern is a valid value (see `LatticeElement`).
            Ok(vec![unsafe { std::mem::zeroed::<T>() }; len].into())
        }
    }

    /// Copies elements `start..start + out.len()` into `out`: from the file of a mapped array.
    fn read_into(&self, start: usize, out: &mut [T]) -> Result<(), CodecError> {
        match &self.inner {
            #[cfg(unix)]
            Inner::Mapped { file, .. } => {
                use std::os::unix::fs::FileExt;
                let size = size_of::<T>();
                // SAFETY: `T` is a plain value type whose every byte pattern the file can hold
                // is valid: the file is written only through `&mut [T]` (see `LatticeElement`),
                // so the bytes read back were a valid `T` when written.
                let bytes = unsafe {
                    std::slice::from_raw_parts_mut(out.as_mut_ptr().cast::<u8>(), size_of_val(out))
                };
                file.read_exact_at(bytes, (start * size) as u64)?;
                // A file mapped by `map_file` was written by another process: a `bool` is
                // made valid before it is read as one.
                if std::any::TypeId::of::<T>() == std::any::TypeId::of::<bool>() {
                    bytes.iter_mut().for_each(|b| *b = u8::from(*b == 1));
                }
            }
            _ => out.copy_from_slice(&self[start..start + out.len()]),
        }
        Ok(())
    }

    /// Drops the resident pages of elements `range` of a mapped array (their values stay in the
    /// file); nothing in memory. Safe while other threads read or write them: they fault the
    /// pages back in from the page cache.
    pub fn release(&self, range: Range<usize>) {
        // Only Unix has `madvise`; elsewhere the pages stay until the kernel needs them.
        #[cfg(unix)]
        if let Inner::Mapped { map, len, .. } = &self.inner {
            let (start, end) = (range.start.min(*len), range.end.min(*len));
            if start < end {
                let size = size_of::<T>();
                // SAFETY: MADV_DONTNEED on a shared file mapping only unmaps pages: their
                // contents stay in the page cache and the file, and later accesses read them
                // back, so no value the program can observe changes.
                let _ = unsafe {
                    map.unchecked_advise_range(
                        UncheckedAdvice::DontNeed,
                        start * size,
                        (end - start) * size,
                    )
                };
            }
        }
        #[cfg(not(unix))]
        let _ = range;
    }

    /// Notes that a pass read about `elements` consecutive values; a mapped array drops all its
    /// resident pages every [`MAPPED_WINDOW_BYTES`] of pages read. Nothing in memory.
    #[inline]
    pub fn touched(&self, elements: usize) {
        self.touched_rows(1, elements);
    }

    /// Notes that a pass read `rows` runs of about `row_len` consecutive values each (rows of
    /// the lattice): counted in whole pages, since a run of a few values maps a page of 4 KiB,
    /// or two where it straddles one. Nothing in memory.
    #[inline]
    pub fn touched_rows(&self, rows: usize, row_len: usize) {
        self.touched_in(rows, row_len, 4096);
    }

    /// [`LatticeArray::touched_rows`] for runs far apart (rows of a coarse diamond, diagonals):
    /// a read fault on a file mapping maps up to 64 KiB around the page (the kernel's fault
    /// around), so each run counts in granules of that.
    #[inline]
    pub fn touched_sparse_rows(&self, rows: usize, row_len: usize) {
        self.touched_in(rows, row_len, 64 << 10);
    }

    #[inline]
    fn touched_in(&self, rows: usize, row_len: usize, granule: usize) {
        if let Inner::Mapped { touched, len, .. } = &self.inner {
            let granules = (row_len * size_of::<T>()).div_ceil(granule) + 1;
            let bytes = (rows * granules * granule) as u64;
            let before = touched.fetch_add(bytes, Ordering::Relaxed);
            if before < MAPPED_WINDOW_BYTES && before + bytes >= MAPPED_WINDOW_BYTES {
                touched.store(0, Ordering::Relaxed);
                self.release(0..*len);
            }
        }
    }

    /// Calls `f` with consecutive windows of the values (their start and the slice), dropping
    /// each window's pages of a mapped array once `f` is done with it: a whole-array scan
    /// whose resident set stays one window.
    pub fn for_each_window(&self, mut f: impl FnMut(usize, &[T])) {
        let window = (MAPPED_WINDOW_BYTES as usize / size_of::<T>()).max(1);
        let mut start = 0;
        while start < self.len() {
            let end = (start + window).min(self.len());
            f(start, &self[start..end]);
            self.release(start..end);
            start = end;
        }
    }

    /// Whether some value satisfies `pred`, scanned by windows ([`LatticeArray::for_each_window`]).
    pub fn any(&self, pred: impl Fn(&T) -> bool) -> bool {
        let mut found = false;
        self.for_each_window(|_, w| found = found || w.iter().any(&pred));
        found
    }
}

/// The bytes of `values`, in the host's byte order.
fn as_bytes<T: LatticeElement>(values: &[T]) -> &[u8] {
    // SAFETY: the element types (`i32`, `u8`, `bool`) have no padding, so every byte of the
    // slice is initialized, and `u8` has no alignment or validity requirement.
    unsafe { std::slice::from_raw_parts(values.as_ptr().cast::<u8>(), size_of_val(values)) }
}

impl<T: LatticeElement> Deref for LatticeArray<T> {
    type Target = [T];

    fn deref(&self) -> &[T] {
        match &self.inner {
            Inner::Heap(v) => v,
            // SAFETY: the mapping holds `len` elements (see `filled`), page-aligned so aligned
            // for `T`, every one a valid `T` (zero or written through this slice type), and it
            // lives as long as `self`.
            Inner::Mapped { map, len, .. } | Inner::Sparse { map, len } => unsafe {
                std::slice::from_raw_parts(map.as_ptr().cast::<T>(), *len)
            },
        }
    }
}

impl<T: LatticeElement> DerefMut for LatticeArray<T> {
    fn deref_mut(&mut self) -> &mut [T] {
        match &mut self.inner {
            Inner::Heap(v) => v,
            // SAFETY: as in `deref`, and `&mut self` makes this the only access.
            Inner::Mapped { map, len, .. } | Inner::Sparse { map, len } => unsafe {
                std::slice::from_raw_parts_mut(map.as_mut_ptr().cast::<T>(), *len)
            },
        }
    }
}

impl<T: LatticeElement> From<Vec<T>> for LatticeArray<T> {
    fn from(v: Vec<T>) -> Self {
        Self {
            inner: Inner::Heap(v),
        }
    }
}

impl<T: LatticeElement> FromIterator<T> for LatticeArray<T> {
    fn from_iter<I: IntoIterator<Item = T>>(iter: I) -> Self {
        iter.into_iter().collect::<Vec<T>>().into()
    }
}

impl<'a, T: LatticeElement> IntoIterator for &'a LatticeArray<T> {
    type Item = &'a T;
    type IntoIter = std::slice::Iter<'a, T>;

    fn into_iter(self) -> Self::IntoIter {
        self.iter()
    }
}

/// A copy in memory, whichever storage the original is in.
impl<T: LatticeElement> Clone for LatticeArray<T> {
    fn clone(&self) -> Self {
        self.to_vec().into()
    }
}

impl<T: LatticeElement> PartialEq for LatticeArray<T> {
    fn eq(&self, other: &Self) -> bool {
        self[..] == other[..]
    }
}

impl<T: LatticeElement + Eq> Eq for LatticeArray<T> {}

impl<T: LatticeElement> fmt::Debug for LatticeArray<T> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match &self.inner {
            Inner::Heap(v) => v.fmt(f),
            Inner::Mapped { len, .. } => write!(f, "LatticeArray(mapped, {len} values)"),
            Inner::Sparse { len, .. } => write!(f, "LatticeArray(window of {len} values)"),
        }
    }
}
