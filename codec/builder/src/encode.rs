//! Encoding a prepared input on a worker pool, and `--extra-levels auto`'s second try.

use cbdam_codec::hierarchy::{
    BlockJournal, EncodeOptions, Encoded, Encoder, NoJournal, Resolution,
};
use cbdam_codec::repository::serialize;

use crate::error::{Result, bail};
use crate::plan::{Prepared, Temporaries, storage_for};

/// Level pairs above the smallest hierarchy that covers the data: a fixed number, or `auto`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ExtraLevels {
    /// None first, then one more where the root field is most of the repository, keeping the
    /// smaller file ([`with_coarser_roots_if_smaller`]).
    Auto,
    /// Exactly this many.
    Fixed(u32),
}

impl ExtraLevels {
    /// The most level pairs accepted: each quadruples the domain's area, and with it the
    /// encoder's reconstruction field (4 bytes a lattice point).
    pub const MAX: u32 = 2;

    /// The level pairs of the first (or only) encode.
    pub fn first(self) -> u32 {
        match self {
            ExtraLevels::Fixed(n) => n,
            ExtraLevels::Auto => 0,
        }
    }
}

/// Encodes a prepared input with `threads` workers (all cores when `None`); variable-resolution
/// data when `resolution` is given. `progress(done, total)` is called from the workers.
pub fn encode_prepared(
    input: &Prepared,
    resolution: Option<&Resolution>,
    opts: &EncodeOptions,
    temporaries: &Temporaries,
    journal: &dyn BlockJournal,
    threads: Option<usize>,
    progress: &(dyn Fn(usize, usize) + Sync),
) -> Result<Encoded> {
    let pool = thread_pool(threads)?;
    let storage = &temporaries.storage;
    Ok(pool.install(|| match (&temporaries.blocks, resolution) {
        (Some(plan), r) => Encoder::new(&input.grid, input.plan.quantizer, opts)
            .per_level(input.plan.levels)
            .resolution(r)
            .storage(storage)
            .in_blocks(plan, journal)
            .progress(progress)
            .encode(),
        (None, Some(r)) => Encoder::new(&input.grid, input.plan.quantizer, opts)
            .per_level(input.plan.levels)
            .resolution(Some(r))
            .storage(storage)
            .progress(progress)
            .encode(),
        (None, None) => Encoder::new(&input.grid, input.plan.quantizer, opts)
            .per_level(input.plan.levels)
            .storage(storage)
            .progress(progress)
            .encode(),
    })?)
}

/// A pool of `threads` workers (all cores when `None`).
pub(crate) fn thread_pool(threads: Option<usize>) -> Result<rayon::ThreadPool> {
    let mut pool = rayon::ThreadPoolBuilder::new();
    if let Some(t) = threads {
        if t == 0 {
            bail!("--threads must be at least 1");
        }
        pool = pool.num_threads(t);
    }
    Ok(pool.build()?)
}

/// `--extra-levels auto` tries one more level pair only where a second encode is cheap ...
pub(crate) const AUTO_RETRY_MAX_SAMPLES: usize = 16 << 20;
/// ... and the root field is at least this share of the repository (percent): only there can
/// sparser roots pay for the coarse records that replace them. Measured on the bundled DEMs
/// (`--extra-levels 0` vs `1`): lidar1m_mn's root field is 47–70 % of the file at 0.5–5 m and
/// one more level pair saves 9 % at 2 m and 39 % at 5 m (but costs 30 % at 0.5 and 1 m, so it
/// must be tried, not assumed); on every other DEM the roots are at most 7 % of the file
/// (Fuji at 5 m) and the difference within ±0.9 %.
const AUTO_RETRY_MIN_ROOT_SHARE: usize = 40;

/// `--extra-levels auto`: when the root field dominates `first` (encoded with
/// `opts.extra_level_pairs`), encodes again with one more level pair and keeps whichever
/// repository is smaller (ties: the first). Also says whether it tried.
pub fn with_coarser_roots_if_smaller(
    input: &Prepared,
    first: Encoded,
    opts: &EncodeOptions,
    limit: u64,
    threads: Option<usize>,
) -> Result<(Encoded, bool)> {
    let size = |e: &Encoded| -> Result<usize> {
        Ok(serialize(e, &input.plan, input.georef.as_ref(), input.nodata)?.len())
    };
    // Large inputs return before anything is serialised: measuring the size would cost a
    // second copy of the repository in memory.
    if input.grid.width * input.grid.height > AUTO_RETRY_MAX_SAMPLES {
        return Ok((first, false));
    }
    let first_size = size(&first)?;
    if first.roots.len() * 100 < first_size * AUTO_RETRY_MIN_ROOT_SHARE {
        return Ok((first, false));
    }
    let opts = EncodeOptions {
        extra_level_pairs: opts.extra_level_pairs + 1,
        ..*opts
    };
    let storage = storage_for(&input.grid, None, &opts, limit)?;
    let second = encode_prepared(
        input,
        None,
        &opts,
        &storage,
        &NoJournal,
        threads,
        &|_, _| {},
    )?;
    Ok((
        if size(&second)? < first_size {
            second
        } else {
            first
        },
        true,
    ))
}
