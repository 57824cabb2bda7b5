//! Planning a planet's lattice before anything is resampled: its level pairs
//! ([`choose_level`]), each input's stride on it ([`input_stride`]), and per lattice tile the
//! stride it holds its points at and the inputs that can cover it ([`plan_tiles`]).

use std::collections::BTreeMap;

use rayon::prelude::*;

use crate::error::{Result, bail};
use crate::planet_input::{Frame, PlanetInput, PlanetInputs};
pub use crate::planet_spacing::{input_stride, lattice_spacing_deg};
use cbdam_codec::geodesy::cube_map::lat_lon_to_face_st;
use cbdam_codec::geometry::{Cube, Domain};
use cbdam_codec::hierarchy::planet::{tile_log2, tile_of};
use cbdam_codec::hierarchy::{PlanetGrid, PlanetTile};

/// The lattice's level pairs `K`: the given one (`--planet-level`, at most 16), or the
/// coarsest at least as fine as the finest input. The lattice is encoded out of core
/// ([`crate::planet_lattice`]), so the memory limit does not coarsen it.
pub fn choose_level(inputs: &PlanetInputs, n: usize, forced: Option<u32>) -> Result<u32> {
    const MAX_K: u32 = 16;
    if let Some(k) = forced {
        if k > MAX_K {
            bail!("--planet-level {k}: at most {MAX_K}");
        }
        return Ok(k);
    }
    let finest = inputs.finest_deg();
    Ok((0..=MAX_K)
        .find(|&k| lattice_spacing_deg(n, k) <= finest * (1.0 + 1e-9))
        .unwrap_or(MAX_K))
}

/// An input that can cover part of a lattice tile: its index, and the rectangle of the tile
/// (`(x0, y0, x1, y1)`, inclusive) it can cover (`None`: the whole tile).
pub type Candidate = (u16, Option<(i64, i64, i64, i64)>);

/// What each tile of a planet's faces holds ([`plan_tiles`]).
pub struct TilePlan {
    /// Per face, per tile: `log2` of the stride of the points it holds.
    pub strides: Vec<Vec<u32>>,
    /// The inputs around the globe (indices into [`PlanetInputs::inputs`], in order): a
    /// candidate of every tile, kept once rather than in each tile's list.
    global: Vec<u16>,
    /// Per face, per tile: the other inputs whose samples lie in or near the tile (in order),
    /// each with the rectangle of the tile it can cover.
    local: Vec<Vec<Vec<Candidate>>>,
}

impl TilePlan {
    /// The inputs that can cover a point of tile `tile` of `face`, finest first (indices into
    /// [`PlanetInputs::inputs`], which are sorted finest first), each with the rectangle of
    /// the tile it can cover: the inputs around the globe (`None`: all of it), and the others
    /// whose samples lie in or near the tile. Only these are asked, and only inside their
    /// rectangles, so a planet of thousands of tiles asks a handful for each point.
    pub fn candidates(&self, face: u8, tile: usize) -> impl Iterator<Item = Candidate> + '_ {
        let mut global = self.global.iter().map(|&i| (i, None)).peekable();
        let mut local = self.local[usize::from(face)][tile]
            .iter()
            .copied()
            .peekable();
        std::iter::from_fn(move || match (global.peek(), local.peek()) {
            (Some(g), Some(l)) if l.0 < g.0 => local.next(),
            (Some(_), _) => global.next(),
            (None, _) => local.next(),
        })
    }
}

/// The stride (`log2`) at which each tile of each face of the `n`, `k` lattice holds its
/// points ([`PlanetGrid`]), and the inputs that can cover it: the finest stride (at most the
/// tile's side) of the inputs around the globe and of those whose samples lie in or near it
/// (within a few of their cells, across face edges too); the tile's side where none does
/// (its corners only, holes). An input's
/// footprint is found from its sample positions (every `q`-th, close enough that no covered
/// lattice point is farther than the margin from one), so a fine inset makes only the tiles
/// around it dense. [`crate::planet::resample`] makes a tile denser still should one of its points turn out to
/// take a finer input's sample.
pub fn plan_tiles(inputs: &PlanetInputs, n: usize, k: u32) -> Result<TilePlan> {
    let domain = Domain::cube_sphere(n, k)?;
    let cube = *domain.cube().expect("a cube-sphere");
    let side = cube.side();
    let t = tile_log2(side);
    let rects = PlanetGrid::tile_rects(&domain, t);
    let strides = inputs.strides(n, k);
    let faces = usize::from(domain.faces());
    // A tile no input reaches holds its corners only (holes all).
    let mut plan = vec![vec![t; rects.len()]; faces];
    let mut global = Vec::new();
    let mut local: Vec<Vec<Vec<Candidate>>> = vec![vec![Vec::new(); rects.len()]; faces];
    for (i, (input, &j)) in inputs.inputs.iter().zip(&strides).enumerate() {
        let i = u16::try_from(i).expect("at most MAX_PLANET_INPUTS inputs");
        let mark = j.min(t);
        if matches!(
            input.frame,
            Frame::Geographic {
                period: Some(_),
                ..
            }
        ) {
            // Around the globe: a candidate everywhere.
            global.push(i);
            for s in plan.iter_mut().flatten() {
                *s = (*s).min(mark);
            }
            continue;
        }
        let (step, reach_of) = footprint(&cube, t, input, j);
        // A covered point of a tile lies within one offset step of a point met there (the
        // offsets are a grid no coarser than `step` over each position's square, and a tile
        // is wider than that).
        for ((face, tile), r) in reach_of {
            let f = usize::from(face);
            plan[f][tile] = plan[f][tile].min(mark);
            let (tx0, ty0, tx1, ty1) = rects[tile];
            let grown = (
                (r.0 - step).max(tx0),
                (r.1 - step).max(ty0),
                (r.2 + step).min(tx1),
                (r.3 + step).min(ty1),
            );
            local[f][tile].push((i, Some(grown)));
        }
    }
    Ok(TilePlan {
        strides: plan,
        global,
        local,
    })
}

/// The points the lattice's tiles will hold, from each tile's stride in [`plan_tiles`] (the
/// resampling may make a tile denser where a point takes a finer input's sample).
pub(crate) fn estimated_held_points(inputs: &PlanetInputs, n: usize, k: u32) -> Result<u64> {
    let domain = Domain::cube_sphere(n, k)?;
    let side = domain.cube().expect("a cube-sphere").side();
    let rects = PlanetGrid::tile_rects(&domain, tile_log2(side));
    let plan = plan_tiles(inputs, n, k)?;
    Ok(plan
        .strides
        .iter()
        .flat_map(|strides| {
            strides.iter().zip(&rects).map(|(&s, &(x0, y0, x1, y1))| {
                (((x1 - x0) >> s) as u64 + 1) * (((y1 - y0) >> s) as u64 + 1)
            })
        })
        .sum())
}

/// Per `(face, tile)`, the rectangle `(x0, y0, x1, y1)` (inclusive) of lattice points an input
/// reaches there.
type Reach = BTreeMap<(u8, usize), (i64, i64, i64, i64)>;

/// Where input `input` (of stride `2^j`, not around the globe) reaches on the lattice of tiles
/// of `2^t` steps: per tile met, the rectangle of the lattice points met (its footprint and a
/// margin of a few of its cells), and the spacing of the offsets that found them (a covered
/// point lies within one such step of a point met).
fn footprint(cube: &Cube, t: u32, input: &PlanetInput, j: u32) -> (i64, Reach) {
    let side = cube.side();
    // Sample positions `q` apart are at most `q·2^(j+1)` lattice steps apart (an input's
    // spacing is under twice its stride); a lattice point it covers lies within one cell
    // of its samples.
    let cell = 2i64 << j;
    // At most a quarter of the tile or of the input apart.
    let q = ((1i64 << t) / (4 * cell))
        .min((input.width.min(input.height) / 4) as i64)
        .max(1) as usize;
    let margin = ((q as i64 + 2) * cell).min(side);
    // Offsets no farther apart than half a tile, so that every tile within the margin is
    // met.
    let step = margin.min(1 << (t - 1)).max(1);
    let mut offsets: Vec<i64> = (0..)
        .map(|m| -margin + m * step)
        .take_while(|&o| o < margin)
        .collect();
    offsets.push(margin);
    let along = |len: usize| (0..len).step_by(q).chain([len - 1]);
    let positions: Vec<(usize, usize)> = along(input.height)
        .flat_map(|r| along(input.width).map(move |c| (c, r)))
        .collect();
    let hits: Vec<(u8, usize, i64, i64)> = positions
        .par_iter()
        .flat_map_iter(|&(c, r)| {
            let (face, s, tt) = lat_lon_to_face_st(input.lat_lon_of(c, r));
            let (x, y) = (
                (s * side as f64).round() as i64,
                (tt * side as f64).round() as i64,
            );
            let mut hits = Vec::new();
            for &dy in &offsets {
                for &dx in &offsets {
                    let Some(p) = cube.locate(face, x + dx, y + dy) else {
                        continue;
                    };
                    let (reps, len) = cube.representations(p);
                    for r in &reps[..len] {
                        hits.push((r.face, tile_of(side, t, r.x, r.y), r.x, r.y));
                    }
                }
            }
            hits
        })
        .collect();
    // Per tile met, the rectangle of the points met (the footprint and its margin there).
    let mut reach_of = Reach::new();
    for (face, tile, x, y) in hits {
        let r = reach_of.entry((face, tile)).or_insert((x, y, x, y));
        *r = (r.0.min(x), r.1.min(y), r.2.max(x), r.3.max(y));
    }
    (step, reach_of)
}

/// The lattice points with data that tile `t` of face `f` owns: a tile owns its first row and
/// column, its last only on the face's edge; an edge point is counted on the face that owns it.
pub(crate) fn valid_in_tile(d: &Domain, f: u8, t: &PlanetTile) -> u64 {
    let side = d.cube().expect("a cube-sphere").side();
    let (x0, y0, x1, y1) = t.rect;
    let step = 1usize << t.stride;
    let mut count = 0u64;
    for (j, y) in (y0..=y1).step_by(step).enumerate() {
        if y == y1 && y1 < side {
            continue;
        }
        for (i, x) in (x0..=x1).step_by(step).enumerate() {
            if (x == x1 && x1 < side) || !t.grid.valid[j * t.grid.width + i] {
                continue;
            }
            let edge = x == 0 || y == 0 || x == side || y == side;
            if !edge || d.canonical_point(f, x, y).is_some_and(|c| c.face == f) {
                count += 1;
            }
        }
    }
    count
}
