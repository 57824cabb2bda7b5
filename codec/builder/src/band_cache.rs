//! Decoded bands of rows of a mosaic's tiles, kept while they fit a byte budget.
//!
//! The mosaic ([`crate::mosaic`]) composes the lattice block of rows by block of rows, north to
//! south; a band of a tile's rows is usually crossed by several blocks, so it is decoded once
//! and kept until it is the least recently used band and the budget is exceeded. The bands of
//! the block being composed are never evicted by that block's own insertions (they are in use),
//! so memory is the budget plus one block's bands, whatever the number and size of the tiles.

use std::collections::{BTreeMap, HashMap};
use std::sync::{Arc, Mutex};

use rayon::prelude::*;

use crate::error::Result;

/// An input's samples in the narrowest type that holds every one of them exactly, NaN included:
/// SRTM's 16-bit integers cost 2 bytes a sample instead of the reader's 8.
#[derive(Debug)]
pub enum Samples {
    /// Whole numbers in the `i16` range.
    I16(Vec<i16>),
    /// Values that `f32` represents exactly, and NaN.
    F32(Vec<f32>),
    /// Anything else.
    F64(Vec<f64>),
}

impl Samples {
    /// The narrowest exact representation of `values`, in memory.
    pub fn compact(values: Vec<f64>) -> Self {
        // `as` saturates and maps NaN to 0, so the round trip fails exactly where the narrow
        // type cannot hold the value (a zero's sign is the only thing dropped).
        if values.iter().all(|&v| f64::from(v as i16) == v) {
            Self::I16(values.iter().map(|&v| v as i16).collect())
        } else if values
            .iter()
            .all(|&v| v.is_nan() || f64::from(v as f32) == v)
        {
            Self::F32(values.iter().map(|&v| v as f32).collect())
        } else {
            Self::F64(values)
        }
    }

    /// An empty [`Samples`] for `len` samples given a band at a time
    /// ([`Samples::push_band`]), in the narrowest representation that has held every band so
    /// far: the samples of a file read a band at a time, never all as `f64` at once.
    pub fn with_capacity(len: usize) -> Self {
        Self::I16(Vec::with_capacity(len))
    }

    /// Appends `band`, keeping the representation [`Samples::compact`] would choose for every
    /// value given so far: `false` (nothing appended) where the band needs a wider one and some
    /// samples are already held — widening them could not restore what the narrowing dropped
    /// (a zero's sign, a NaN's payload), so the caller compacts the whole instead.
    pub fn push_band(&mut self, band: &[f64]) -> bool {
        let fits_i16 = || band.iter().all(|&v| f64::from(v as i16) == v);
        let fits_f32 = || band.iter().all(|&v| v.is_nan() || f64::from(v as f32) == v);
        if let Self::I16(v) = self {
            if fits_i16() {
                v.extend(band.iter().map(|&x| x as i16));
                return true;
            }
            if !v.is_empty() {
                return false;
            }
            *self = Self::F32(Vec::with_capacity(v.capacity()));
        }
        if let Self::F32(v) = self {
            if fits_f32() {
                v.extend(band.iter().map(|&x| x as f32));
                return true;
            }
            if !v.is_empty() {
                return false;
            }
            *self = Self::F64(Vec::with_capacity(v.capacity()));
        }
        if let Self::F64(v) = self {
            v.extend_from_slice(band);
        }
        true
    }

    /// Sample `i`.
    #[inline]
    pub fn get(&self, i: usize) -> f64 {
        match self {
            Self::I16(v) => f64::from(v[i]),
            Self::F32(v) => f64::from(v[i]),
            Self::F64(v) => v[i],
        }
    }

    /// Bytes of the samples.
    pub fn bytes(&self) -> u64 {
        match self {
            Self::I16(v) => 2 * v.len() as u64,
            Self::F32(v) => 4 * v.len() as u64,
            Self::F64(v) => 8 * v.len() as u64,
        }
    }
}

/// Samples read one at a time by index, as `f64`: each held representation on its own (a
/// loop over one of them reads without matching on the representation each time), and
/// [`Samples`] itself.
pub trait SampleValues: Sync {
    /// Sample `i`.
    fn value(&self, i: usize) -> f64;
}

impl SampleValues for [i16] {
    #[inline]
    fn value(&self, i: usize) -> f64 {
        f64::from(self[i])
    }
}

impl SampleValues for [f32] {
    #[inline]
    fn value(&self, i: usize) -> f64 {
        f64::from(self[i])
    }
}

impl SampleValues for [f64] {
    #[inline]
    fn value(&self, i: usize) -> f64 {
        self[i]
    }
}

impl SampleValues for Samples {
    #[inline]
    fn value(&self, i: usize) -> f64 {
        self.get(i)
    }
}

/// A band: tile index and band number within the tile.
pub type BandKey = (usize, usize);

#[derive(Default)]
struct State {
    /// Band → samples and the tick of its last use.
    bands: HashMap<BandKey, (Arc<Samples>, u64)>,
    /// Tick of last use → band: the eviction order.
    by_use: BTreeMap<u64, BandKey>,
    bytes: u64,
    tick: u64,
}

/// The cache; see the module notes.
pub struct BandCache {
    budget: u64,
    state: Mutex<State>,
    decoded: std::sync::atomic::AtomicU64,
}

impl BandCache {
    /// An empty cache holding at most `budget` bytes of bands besides those in use.
    pub fn new(budget: u64) -> Self {
        Self {
            budget,
            state: Mutex::new(State::default()),
            decoded: std::sync::atomic::AtomicU64::new(0),
        }
    }

    /// The bytes it may keep.
    pub fn budget(&self) -> u64 {
        self.budget
    }

    /// Bands decoded so far (hits excluded).
    pub fn decoded(&self) -> u64 {
        self.decoded.load(std::sync::atomic::Ordering::Relaxed)
    }

    /// The samples of every band in `keys` (in that order): kept ones, and the others decoded
    /// by `decode` in parallel and kept while the budget allows.
    pub fn get(
        &self,
        keys: &[BandKey],
        decode: impl Fn(BandKey) -> Result<Samples> + Sync,
    ) -> Result<Vec<Arc<Samples>>> {
        let lock = || self.state.lock().unwrap_or_else(|e| e.into_inner());
        let mut found: Vec<Option<Arc<Samples>>> = Vec::with_capacity(keys.len());
        let first_tick;
        {
            let mut s = lock();
            s.tick += 1;
            first_tick = s.tick;
            for key in keys {
                let tick = s.tick;
                let hit = match s.bands.get_mut(key) {
                    Some((samples, used)) => {
                        let old = std::mem::replace(used, tick);
                        Some((samples.clone(), old))
                    }
                    None => None,
                };
                found.push(hit.map(|(samples, old)| {
                    s.by_use.remove(&old);
                    s.by_use.insert(tick, *key);
                    s.tick += 1;
                    samples
                }));
            }
        }
        let missing: Vec<usize> = (0..keys.len()).filter(|&i| found[i].is_none()).collect();
        let decoded = missing
            .par_iter()
            .map(|&i| decode(keys[i]).map(Arc::new))
            .collect::<Result<Vec<_>>>()?;
        self.decoded
            .fetch_add(decoded.len() as u64, std::sync::atomic::Ordering::Relaxed);
        let mut s = lock();
        for (&i, samples) in missing.iter().zip(decoded) {
            let tick = s.tick;
            s.tick += 1;
            s.bytes += samples.bytes();
            if let Some((_, old)) = s.bands.insert(keys[i], (samples.clone(), tick)) {
                // Decoded twice by concurrent callers: the older copy goes.
                s.by_use.remove(&old);
            }
            s.by_use.insert(tick, keys[i]);
            found[i] = Some(samples);
        }
        // Evict the least recently used bands of earlier calls while over budget.
        while s.bytes > self.budget {
            let Some((&tick, &key)) = s.by_use.iter().next() else {
                break;
            };
            if tick >= first_tick {
                break;
            }
            s.by_use.remove(&tick);
            if let Some((samples, _)) = s.bands.remove(&key) {
                s.bytes -= samples.bytes();
            }
        }
        Ok(found
            .into_iter()
            .map(|f| f.expect("every band found or decoded"))
            .collect())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Samples given a band at a time are what [`Samples::compact`] makes of them all, in
    /// the same representation (zeros' signs and NaN included), or refused where a band needs
    /// a wider representation than the samples already held.
    #[test]
    fn samples_pushed_band_by_band_are_the_whole_compacted() {
        let bands: [&[&[f64]]; 6] = [
            &[&[1.0, -2.0], &[300.0, -32768.0]],
            &[&[0.5, 2.0], &[-0.0, f64::NAN]],
            &[&[1.0e300, 2.0], &[0.1, f64::NAN]],
            &[&[], &[1.0, 2.0]],
            &[&[1.0, 2.0], &[0.5]],
            &[&[1.0, 2.5], &[0.1]],
        ];
        for (case, bands) in bands.iter().enumerate() {
            let all: Vec<f64> = bands.iter().flat_map(|b| b.iter().copied()).collect();
            let mut pushed = Samples::with_capacity(all.len());
            let taken = bands.iter().all(|b| pushed.push_band(b));
            let whole = Samples::compact(all.clone());
            if case >= 4 {
                assert!(
                    !taken,
                    "case {case}: a wider band after narrow samples is refused"
                );
                continue;
            }
            assert!(taken, "case {case}");
            let bits =
                |s: &Samples| -> Vec<u64> { (0..all.len()).map(|i| s.get(i).to_bits()).collect() };
            assert_eq!(
                std::mem::discriminant(&pushed),
                std::mem::discriminant(&whole),
                "case {case}"
            );
            assert_eq!(bits(&pushed), bits(&whole), "case {case}");
        }
    }

    /// Hits are not decoded again; bands of earlier calls are evicted least recently used first
    /// once over budget, but never those of the current call.
    #[test]
    fn keeps_recent_bands_within_the_budget() {
        let decodes = std::sync::atomic::AtomicUsize::new(0);
        let decode = |(t, b): BandKey| {
            decodes.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            Ok(Samples::compact(vec![(t * 10 + b) as f64; 100]))
        };
        // 200 bytes a band (i16), budget of two bands.
        let cache = BandCache::new(400);
        let got = cache.get(&[(0, 0), (0, 1), (1, 0)], decode).unwrap();
        assert_eq!(got[2].get(0), 10.0);
        assert_eq!(decodes.load(std::sync::atomic::Ordering::Relaxed), 3);
        // Over budget, but all three were in use. The next call evicts the least recently used
        // band of earlier calls, (0, 0), down to the budget.
        cache.get(&[(0, 1)], decode).unwrap();
        assert_eq!(decodes.load(std::sync::atomic::Ordering::Relaxed), 3);
        // A new band evicts (1, 0); (0, 1) and (2, 0) stay.
        cache.get(&[(2, 0)], decode).unwrap();
        cache.get(&[(0, 1), (2, 0)], decode).unwrap();
        assert_eq!(decodes.load(std::sync::atomic::Ordering::Relaxed), 4);
        cache.get(&[(0, 0)], decode).unwrap();
        assert_eq!(decodes.load(std::sync::atomic::Ordering::Relaxed), 5);
        assert_eq!(cache.decoded(), 5);
        assert!(cache.state.lock().unwrap().bytes <= 400);
    }
}
