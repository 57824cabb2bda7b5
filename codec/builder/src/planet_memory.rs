//! What a block-wise planet build holds whatever its `--memory-limit` (its *floor*), and how it
//! shares the rest of the limit out between its caches and its blocks ([`PlanetMemory`]).
//!
//! The floor is the process itself, the inputs kept for the whole build (those around the
//! globe, which every lattice tile asks for), the cube map's tables and the per-tile tables of
//! the lattice, the spills' in-memory parts and what each worker holds while it paints one
//! tile and reads one input. The limit less the floor is shared between the inputs' cache
//! (a fifth), the lattice tiles' cache and the blocks (two fifths each). A limit under the
//! floor plus the least those three need ([`PlanetMemory::minimum`]) cannot be kept: the build
//! says so before it starts (naming the minimum) and runs at the minimum's budgets.

use crate::error::Result;
use crate::planet_input::PlanetInputs;
use cbdam_codec::hierarchy::planet::tile_log2;

/// The program's own resident memory: its code and data, its threads' stacks and the C
/// allocator's bookkeeping (about 11 MiB at the peak of a planet build: its RSS less its heap,
/// `heaptrack`, 2026-12-07), rounded up.
pub const PROCESS_BYTES: u64 = 16 << 20;

/// Bytes a lattice tile's tables take a tile (its rectangle in the lattice, the apex view's,
/// the tile plan's entry and the view's offsets): about 100 a tile, rounded up.
const TABLE_BYTES_PER_TILE: u64 = 128;

/// Bytes a point of a tile takes while it is painted (height, validity, winner, class, done).
const PAINT_BYTES_PER_POINT: u64 = 4 + 1 + 2 + 1 + 1;

/// Bytes a point of a tile takes while it is held (height, validity, class, winner).
const HELD_BYTES_PER_POINT: u64 = 4 + 1 + 1 + 2;

/// Bytes a sample of an input being read takes: the narrowest samples (2 B) and the band of
/// wider ones it is read through, taken at most as many again.
const READ_BYTES_PER_SAMPLE: u64 = 4;

/// A planet build's memory: its floor, part by part, and the limit it runs under.
#[derive(Clone, Debug)]
pub struct PlanetMemory {
    /// What the build holds whatever the limit, by owner, bytes.
    pub floor: Vec<(&'static str, u64)>,
    /// Bytes of a finest lattice tile held (the least unit of the caches and blocks).
    pub tile_bytes: u64,
    /// The `--memory-limit` asked for.
    pub limit: u64,
}

impl PlanetMemory {
    /// The memory of a build of `inputs` on the `n`, `k` lattice, on `threads` workers, under
    /// `limit`. The inputs kept for the whole build are counted at their samples' size once
    /// read (they are read for the height range first).
    pub fn new(
        inputs: &PlanetInputs,
        (n, k): (usize, u32),
        threads: usize,
        limit: u64,
    ) -> Result<Self> {
        let domain = cbdam_codec::geometry::Domain::cube_sphere(n, k)?;
        let side = domain.cube().expect("a cube-sphere").side();
        let tile_side = 1u64 << tile_log2(side);
        let side = side.max(1) as u64;
        let tiles = 6 * (side / tile_side).pow(2);
        let tile_points = (tile_side + 1).pow(2);
        let read = inputs
            .inputs
            .iter()
            .enumerate()
            .filter(|(i, _)| !inputs.cache.is_pinned(*i))
            .map(|(_, i)| (i.width * i.height) as u64 * READ_BYTES_PER_SAMPLE)
            .max()
            .unwrap_or(0);
        let threads = threads.max(1) as u64;
        let floor = vec![
            ("the program, its threads' stacks", PROCESS_BYTES),
            ("inputs around the globe, kept", inputs.pinned_bytes()?),
            // A table of the cube's warp, and per equatorial face one of its columns.
            ("the cube map's tables", (side + 1) * (8 + 4 * 16)),
            ("the lattice tiles' tables", tiles * TABLE_BYTES_PER_TILE),
            ("the spills' in-memory parts", spills_in_memory_bytes()),
            (
                "each worker painting a tile and reading an input",
                threads * (tile_points * PAINT_BYTES_PER_POINT + read),
            ),
        ];
        Ok(Self {
            floor,
            tile_bytes: tile_points * HELD_BYTES_PER_POINT,
            limit,
        })
    }

    /// The floor's bytes.
    pub fn floor_bytes(&self) -> u64 {
        self.floor.iter().map(|&(_, b)| b).sum()
    }

    /// The least limit the build keeps: its floor and, for its caches and blocks, four finest
    /// tiles (a block of one, two in the lattice cache, one input or so in the inputs' cache).
    pub fn minimum(&self) -> u64 {
        self.floor_bytes() + 4 * self.tile_bytes
    }

    /// What the caches and blocks share: the limit (at least the minimum) less the floor.
    fn shared(&self) -> u64 {
        self.limit.max(self.minimum()) - self.floor_bytes()
    }

    /// Bytes of the inputs' samples kept besides those in use and those kept for the whole
    /// build: a fifth of what is shared.
    pub fn input_cache_budget(&self) -> u64 {
        self.shared() / 5
    }

    /// Bytes of resampled lattice tiles kept for the blocks that read them again: two fifths.
    pub fn lattice_cache_budget(&self) -> u64 {
        self.shared() * 2 / 5
    }

    /// Bytes one block is planned to hold ([`crate::planet::planet_block_bytes`]): two fifths.
    pub fn block_bytes(&self) -> u64 {
        self.shared() * 2 / 5
    }

    /// Where the limit is under [`PlanetMemory::minimum`]: what to tell the user, naming the
    /// minimum and the largest parts of the floor.
    pub fn too_small(&self) -> Option<String> {
        if self.limit >= self.minimum() {
            return None;
        }
        let mib = |b: u64| b as f64 / f64::from(1 << 20);
        let mut parts = self.floor.clone();
        parts.sort_by_key(|&(_, b)| std::cmp::Reverse(b));
        let parts: Vec<String> = parts
            .iter()
            .map(|&(what, b)| format!("{what} {:.0} MiB", mib(b)))
            .collect();
        Some(format!(
            "--memory-limit {:.0} MiB is under this planet's minimum of about {:.0} MiB (what the \
             build holds whatever the limit: {}; and four lattice tiles of {:.1} MiB for its \
             caches and blocks); the build runs within about {:.0} MiB",
            mib(self.limit),
            mib(self.minimum()),
            parts.join(", "),
            mib(self.tile_bytes),
            mib(self.minimum()),
        ))
    }
}

/// Bytes the planet encoder's temporary files keep in memory before they go to disk: the
/// apex's grids, its refinements and the apex view.
fn spills_in_memory_bytes() -> u64 {
    use cbdam_codec::hierarchy::planet::{
        APEX_GRIDS_IN_MEMORY_BYTES, APEX_REFINEMENTS_IN_MEMORY_BYTES, APEX_VIEW_IN_MEMORY_BYTES,
    };
    (APEX_GRIDS_IN_MEMORY_BYTES + APEX_REFINEMENTS_IN_MEMORY_BYTES + APEX_VIEW_IN_MEMORY_BYTES)
        as u64
}
