//! The planet lattice out of core: each lattice tile resampled from the inputs when the
//! block-wise encode ([`PlanetBlocks`]) or the resampling-error scan asks for it,
//! through a bounded cache, never the whole lattice held (in memory or on disk).
//!
//! A build resamples every tile once to outline the planet (its stored diamonds, nodata, the
//! valid points; [`PlanetOutline`]) and to fix the stride each tile holds its points at (denser
//! than planned where a point took a finer input's sample), then again as the apex (thinned to
//! the cut's vertices), the blocks (each its tile and the strips of its neighbours its diamonds
//! reach) and each input's resampling error (the tiles its samples lie in, thinned to its
//! stride) ask. A point's height depends on the point and the inputs only, so every reading of
//! a tile holds the same values: the repository is byte for byte the one the whole lattice
//! encodes to.

use std::collections::{HashMap, VecDeque};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex};

use rayon::prelude::*;

use crate::band_cache::{SampleValues, Samples};
use crate::error::{BuildError, Result};
use crate::planet_input::{PlanetInputs, PointSource};
use crate::planet_plan::{TilePlan, lattice_spacing_deg, plan_tiles, valid_in_tile};
use crate::planet_resampling::{InputResampling, Resampled, sample_footprint};
use cbdam_codec::CodecError;
use cbdam_codec::geodesy::cube_map::FaceLattice;
use cbdam_codec::geodesy::lattice_lat_lon;
use cbdam_codec::geometry::Domain;
use cbdam_codec::hierarchy::planet::{ApexViewWriter, PlanetOutline, PlanetTiles, tile_log2};
use cbdam_codec::hierarchy::resolution::{COARSE_ONLY, HOLE};
use cbdam_codec::hierarchy::{PlanetGrid, PlanetTile};
use cbdam_codec::quant::{HeightGrid, QuantPlan};

/// How many inputs' samples a tile's painting holds at once.
const INPUTS_HELD: usize = 4;

/// Lattice points `(x0, y0, x1, y1)` of a face, inclusive.
type Rect = (i64, i64, i64, i64);

/// One tile's points at a stride: heights, validity, winning inputs, classes, and the finest
/// class of a sample among them.
type Painted = (Vec<i32>, Vec<bool>, Vec<u16>, Vec<u8>, Option<u8>);

/// Resamples the inputs onto the tiles of the `N`, `K` cube-sphere, one tile at a time (see
/// [`crate::planet`]'s documentation for the rule each point follows).
pub struct Resampler<'a> {
    inputs: &'a PlanetInputs,
    plan: &'a QuantPlan,
    domain: Domain,
    side: i64,
    tile_log2: u32,
    lattice_deg: f64,
    /// Per input, `log2` of its stride on the lattice.
    strides: Vec<u32>,
    variable: bool,
    tiles: TilePlan,
    rects: Vec<(i64, i64, i64, i64)>,
    lattices: Vec<FaceLattice>,
    /// Lattice points painted so far: all, and those of parts of tiles.
    painted: AtomicU64,
    painted_parts: AtomicU64,
    /// Points the outline found covered by a fine input's valid samples, not painted.
    covered: AtomicU64,
}

impl<'a> Resampler<'a> {
    /// The resampler of `inputs` onto the `n`, `k` lattice, heights in units of `plan`.
    pub fn new(inputs: &'a PlanetInputs, n: usize, k: u32, plan: &'a QuantPlan) -> Result<Self> {
        let domain = Domain::cube_sphere(n, k)?;
        let side = domain.cube().expect("a cube-sphere").side();
        let strides = inputs.strides(n, k);
        let tile_log2 = tile_log2(side);
        Ok(Self {
            inputs,
            plan,
            domain,
            side,
            tile_log2,
            lattice_deg: lattice_spacing_deg(n, k),
            variable: strides.iter().any(|&j| j > 0),
            strides,
            tiles: plan_tiles(inputs, n, k)?,
            rects: PlanetGrid::tile_rects(&domain, tile_log2),
            lattices: FaceLattice::faces(side),
            painted: AtomicU64::new(0),
            painted_parts: AtomicU64::new(0),
            covered: AtomicU64::new(0),
        })
    }

    /// The lattice's cube-sphere.
    pub fn domain(&self) -> &Domain {
        &self.domain
    }

    /// `log2` of the tiles' side.
    pub fn tile_log2(&self) -> u32 {
        self.tile_log2
    }

    /// Whether the tiles carry resolution classes (an input coarser than the lattice).
    pub fn is_variable(&self) -> bool {
        self.variable
    }

    /// Per input, `log2` of its stride on the lattice.
    pub fn input_strides(&self) -> &[u32] {
        &self.strides
    }

    /// Tiles per face.
    pub fn tiles_per_face(&self) -> usize {
        self.rects.len()
    }

    /// Tile `tile` of `face` at the stride the plan gives it, or denser where a point took a
    /// finer input's sample than planned: the tile a whole resampling holds, with the winning
    /// input of each point.
    pub fn final_tile(&self, face: u8, tile: usize) -> Result<(PlanetTile, Vec<u16>)> {
        let mut s = self.tiles.strides[usize::from(face)][tile];
        let mut painted = self.paint(face, tile, s, None, None)?;
        // A point that took a finer input's sample than planned: the tile holds every point
        // of that input's stride.
        if let Some(j) = painted.4.filter(|&j| u32::from(j) < s) {
            s = u32::from(j);
            painted = self.paint(face, tile, s, None, None)?;
        }
        self.tile_of(tile, s, painted)
    }

    /// Tile `tile` of `face` as the outline needs it: [`Resampler::final_tile`]'s stride,
    /// classes and validity, but the points of squares proved to take a valid sample of a fine
    /// input (`planet_lattice_covered.rs`) not painted: they hold height 0 (the outline reads
    /// no height) — except the points on multiples of `2^keep` where `keep` is given (what the
    /// apex view keeps of the tile: their heights are [`Resampler::final_tile`]'s).
    pub fn outline_tile(&self, face: u8, tile: usize, keep: Option<u32>) -> Result<PlanetTile> {
        let Some(mut covered) = self.covered_points(face, tile)? else {
            return Ok(self.final_tile(face, tile)?.0);
        };
        if let Some(keep) = keep {
            self.paint_multiples(tile, keep, &mut covered);
        }
        // Held at stride 1 (`covered_points`), so no point can take a finer input's sample.
        let painted = self.paint(face, tile, 0, None, Some(&covered))?;
        Ok(self.tile_of(tile, 0, painted)?.0)
    }

    /// Clears in `covered` (a mask of tile `tile`'s points at stride 1) the points whose
    /// lattice coordinates are both multiples of `2^stride`.
    fn paint_multiples(&self, tile: usize, stride: u32, covered: &mut [bool]) {
        let (x0, y0, _, _) = self.rects[tile];
        let (w, h) = self.tile_size(tile, 0);
        let on = |c: i64| c & ((1i64 << stride) - 1) == 0;
        for row in (0..h).filter(|&r| on(y0 + r as i64)) {
            for col in (0..w).filter(|&c| on(x0 + c as i64)) {
                covered[row * w + col] = false;
            }
        }
    }

    /// Tile `tile` of `face` holding its points on multiples of `2^stride`.
    pub fn tile(&self, face: u8, tile: usize, stride: u32) -> Result<(PlanetTile, Vec<u16>)> {
        let painted = self.paint(face, tile, stride, None, None)?;
        self.tile_of(tile, stride, painted)
    }

    /// [`Resampler::tile`] with only its points in `part` (inclusive) painted, the others
    /// holes.
    pub fn tile_part(
        &self,
        face: u8,
        tile: usize,
        stride: u32,
        part: Rect,
    ) -> Result<(PlanetTile, Vec<u16>)> {
        let painted = self.paint(face, tile, stride, Some(part), None)?;
        self.tile_of(tile, stride, painted)
    }

    fn tile_of(&self, tile: usize, s: u32, painted: Painted) -> Result<(PlanetTile, Vec<u16>)> {
        let (values, valid, won, class, _) = painted;
        let rect = self.rects[tile];
        let (x0, y0, x1, y1) = rect;
        let grid = HeightGrid {
            width: ((x1 - x0) >> s) as usize + 1,
            height: ((y1 - y0) >> s) as usize + 1,
            values: values.into(),
            valid: valid.into(),
        };
        let tile = PlanetTile::new(s, rect, grid, self.variable.then_some(class))?;
        Ok((tile, won))
    }

    /// One tile's points at stride `2^s`. The inputs that can cover the tile paint it finest
    /// first, each over its own rectangle, each point taking the first that covers it; only
    /// the points in `part` where one is given. A point's position is computed once, however
    /// many inputs' rectangles hold it. The points `covered` names (at stride 1, the whole
    /// tile) are not painted: valid, class 0, height 0 and no winner.
    fn paint(
        &self,
        face: u8,
        tile: usize,
        s: u32,
        part: Option<Rect>,
        covered: Option<&[bool]>,
    ) -> Result<Painted> {
        let rect = self.rects[tile];
        let (x0, y0, _, _) = rect;
        let (w, h) = self.tile_size(tile, s);
        let mut values = vec![0; w * h];
        let mut won = vec![u16::MAX; w * h];
        let (mut valid, mut class, mut done) = unpainted(w * h, covered);
        let reaching = self.reaching(face, tile, s, part);
        self.count_painted((w, h), (x0, y0), s, part, covered);
        // The inputs a few at a time (read, or found in the cache, only now, and let go when
        // they have painted), so that the samples held do not grow with the candidates.
        for chunk in reaching.chunks(INPUTS_HELD) {
            let chunk = chunk
                .iter()
                .map(|&(input, span)| {
                    let samples = self.inputs.samples(usize::from(input))?;
                    let columns = self.input_columns(face, input, (x0, s), (span.0, span.1));
                    Ok((input, span, samples, columns))
                })
                .collect::<Result<Vec<_>>>()?;
            values
                .par_chunks_mut(w)
                .zip(valid.par_chunks_mut(w))
                .zip(won.par_chunks_mut(w))
                .zip(class.par_chunks_mut(w))
                .zip(done.par_chunks_mut(w))
                .enumerate()
                .try_for_each_init(
                    Vec::new,
                    |positions, (row, ((((values, valid), won), class), done))| -> Result<()> {
                        let y = y0 + ((row as i64) << s);
                        let mut out = RowOut {
                            values,
                            valid,
                            won,
                            class,
                            done,
                            positions,
                        };
                        out.positions.clear();
                        out.positions.resize(w, None);
                        // Input by input, each over its columns of the row: a point asks the
                        // inputs in the same order as one at a time would, and stops at the same.
                        for (input, (c0, c1, r0, r1), samples, columns) in &chunk {
                            if row < *r0 || row > *r1 {
                                continue;
                            }
                            let run = Run {
                                face,
                                x0,
                                y,
                                s,
                                columns: *c0..=*c1,
                                // Edge rows' points are located through their owner face.
                                input_columns: columns.as_deref().filter(|_| self.inside(y)),
                            };
                            self.paint_run_of(&mut out, &run, *input, samples)?;
                        }
                        Ok(())
                    },
                )?;
        }
        let finest = class.iter().copied().filter(|&c| c < 32).min();
        Ok((values, valid, won, class, finest))
    }

    /// [`Resampler::paint_run`] from samples in whichever representation they are held.
    fn paint_run_of(
        &self,
        out: &mut RowOut,
        run: &Run,
        input: u16,
        samples: &Samples,
    ) -> Result<()> {
        match samples {
            Samples::I16(v) => self.paint_run(out, run, input, v.as_slice()),
            Samples::F32(v) => self.paint_run(out, run, input, v.as_slice()),
            Samples::F64(v) => self.paint_run(out, run, input, v.as_slice()),
        }
    }

    /// Paints the points of `run` not yet done from input `input` (`samples` its samples), where it
    /// covers them: a point's position is worked out once, the first time an input asks. A
    /// height the plan cannot hold (infinite, or outside the planned range) is an error naming
    /// the input and the point; a NaN one is no data.
    fn paint_run<S: SampleValues + ?Sized>(
        &self,
        out: &mut RowOut,
        run: &Run,
        input: u16,
        samples: &S,
    ) -> Result<()> {
        let probe = self
            .inputs
            .probe(samples, input, self.lattice_deg, &self.strides);
        let first = *run.columns.start();
        for i in run.columns.clone() {
            if out.done[i] {
                continue;
            }
            let x = run.x0 + ((i as i64) << run.s);
            let column = run
                .input_columns
                .filter(|_| self.inside(x))
                .map(|columns| columns[i - first]);
            // Off the input in longitude: no position needed to know it does not cover the point.
            if column == Some(None) {
                continue;
            }
            let ll = *out.positions[i].get_or_insert_with(|| self.lat_lon(run.face, x, run.y));
            let source = match column {
                Some(Some(c)) => probe.source_in_column(ll, c, (x, run.y)),
                _ => probe.source_of(ll, (x, run.y)),
            };
            match source {
                Some(PointSource::Sample(v, wi, j)) => {
                    let units = self
                        .plan
                        .to_units(v)
                        .map_err(|e| self.unplanned_height(e, input, (run.face, x, run.y), ll))?;
                    if let Some(u) = units {
                        out.values[i] = u;
                        out.valid[i] = true;
                        out.won[i] = wi;
                        out.class[i] = j;
                    }
                    out.done[i] = true;
                }
                Some(PointSource::CoarseOnly(wi)) => {
                    out.won[i] = wi;
                    out.class[i] = COARSE_ONLY;
                    out.done[i] = true;
                }
                None => {}
            }
        }
        Ok(())
    }

    /// The error of a height from input `input` at lattice point `(face, x, y)` (at `ll`) that
    /// the plan cannot hold.
    fn unplanned_height(
        &self,
        e: CodecError,
        input: u16,
        (face, x, y): (u8, i64, i64),
        ll: cbdam_codec::geodesy::LatLon,
    ) -> BuildError {
        let path = self.inputs.inputs[usize::from(input)].path.display();
        BuildError::Invalid(format!(
            "{path}: its height at lattice point ({x}, {y}) of face {face} ({:.6}°, {:.6}°) \
             cannot be stored: {e}",
            ll.lat, ll.lon
        ))
    }

    /// Adds the points of a `w × h` tile at `(x0, y0)`, stride `2^s` (of `part` only where one
    /// is given), to those painted, less those `covered` names (counted apart).
    fn count_painted(
        &self,
        (w, h): (usize, usize),
        (x0, y0): (i64, i64),
        s: u32,
        part: Option<Rect>,
        covered: Option<&[bool]>,
    ) {
        if let Some(c) = covered {
            let n = c.iter().filter(|&&c| c).count() as u64;
            self.painted.fetch_sub(n, Ordering::Relaxed);
            self.covered.fetch_add(n, Ordering::Relaxed);
        }
        let painted = match part {
            None => (w * h) as i64,
            // The part's points on the stride.
            Some((px0, py0, px1, py1)) => {
                let step = 1i64 << s;
                let (x1, y1) = (x0 + ((w as i64 - 1) << s), y0 + ((h as i64 - 1) << s));
                let count = |lo: i64, hi: i64, o: i64, end: i64| {
                    let (lo, hi) = ((lo.max(o) - o + step - 1) / step, (hi.min(end) - o) / step);
                    (hi - lo + 1).max(0)
                };
                count(px0, px1, x0, x1) * count(py0, py1, y0, y1)
            }
        };
        self.painted.fetch_add(painted as u64, Ordering::Relaxed);
        if part.is_some() {
            self.painted_parts
                .fetch_add(painted as u64, Ordering::Relaxed);
        }
    }

    /// Where `face`'s lattice columns share a longitude (an equatorial face) and input `input`
    /// lies on a latitude/longitude grid: the input's column ([`PlanetInput::pixel_column`],
    /// `None` off it) of each tile column `c0..=c1` (in points of stride `2^s` from `x0`),
    /// worked out once for all the tile's rows. Columns on the face's edges are located
    /// through their owner face and are not looked up here.
    ///
    /// [`PlanetInput::pixel_column`]: crate::planet_input::PlanetInput::pixel_column
    fn input_columns(
        &self,
        face: u8,
        input: u16,
        (x0, s): (i64, u32),
        (c0, c1): (usize, usize),
    ) -> Option<Vec<Option<f64>>> {
        let lattice = &self.lattices[usize::from(face)];
        let input = &self.inputs.inputs[usize::from(input)];
        lattice.column_lon(0)?;
        input.is_geographic().then(|| {
            (c0..=c1)
                .map(|i| {
                    let x = x0 + ((i as i64) << s);
                    let lon = self.inside(x).then(|| lattice.column_lon(x as usize))??;
                    input.pixel_column(lon)
                })
                .collect()
        })
    }

    /// Whether lattice coordinate `c` lies strictly inside the face (a point with both inside
    /// is its own canonical point: [`Resampler::lat_lon`]).
    #[inline]
    fn inside(&self, c: i64) -> bool {
        0 < c && c < self.side
    }

    /// Points a row and rows of tile `tile` at stride `2^s`.
    fn tile_size(&self, tile: usize, s: u32) -> (usize, usize) {
        let (x0, y0, x1, y1) = self.rects[tile];
        (((x1 - x0) >> s) as usize + 1, ((y1 - y0) >> s) as usize + 1)
    }

    /// The inputs that can cover a point of tile `tile` of `face` on stride `2^s` (in `part`
    /// where one is given), finest first, each with the columns and rows (`c0, c1, r0, r1`,
    /// inclusive, in points of the stride) of its rectangle there.
    fn reaching(
        &self,
        face: u8,
        tile: usize,
        s: u32,
        part: Option<Rect>,
    ) -> Vec<(u16, (usize, usize, usize, usize))> {
        let rect = self.rects[tile];
        let (x0, y0, x1, y1) = rect;
        let within = |r: Rect| match part {
            None => r,
            Some(p) => (r.0.max(p.0), r.1.max(p.1), r.2.min(p.2), r.3.min(p.3)),
        };
        let (w, h) = self.tile_size(tile, s);
        let step = 1i64 << s;
        let first = |lo: i64, o: i64| ((lo.max(o) - o + step - 1) / step) as usize;
        let last = |hi: i64, o: i64, n: usize| (((hi - o) / step) as usize).min(n - 1);
        self.tiles
            .candidates(face, tile)
            .filter_map(|(input, reach)| {
                let (rx0, ry0, rx1, ry1) = within(reach.unwrap_or(rect));
                if rx1 < x0 || ry1 < y0 || rx0 > x1 || ry0 > y1 {
                    return None;
                }
                let (c0, c1) = (first(rx0, x0), last(rx1, x0, w));
                let (r0, r1) = (first(ry0, y0), last(ry1, y0, h));
                (c0 <= c1 && r0 <= r1).then_some((input, (c0, c1, r0, r1)))
            })
            .collect()
    }

    /// Lattice points painted so far (a point painted again counts again): all, and those of
    /// parts of tiles.
    pub fn painted(&self) -> (u64, u64) {
        (
            self.painted.load(Ordering::Relaxed),
            self.painted_parts.load(Ordering::Relaxed),
        )
    }

    /// Points the outline found covered by a fine input's valid samples and did not paint
    /// ([`Resampler::outline_tile`]).
    pub fn covered(&self) -> u64 {
        self.covered.load(Ordering::Relaxed)
    }

    /// The geodetic position of lattice point `(x, y)` of `face`. Interior points are their own
    /// canonical point; edge and corner points are computed from their owner, so every face
    /// holding one sees the same bits.
    #[inline]
    fn lat_lon(&self, face: u8, x: i64, y: i64) -> cbdam_codec::geodesy::LatLon {
        if 0 < x && x < self.side && 0 < y && y < self.side {
            self.lattices[usize::from(face)].lat_lon(x as usize, y as usize)
        } else {
            lattice_lat_lon(&self.domain, face, x, y).expect("a point of the face")
        }
    }
}

/// Validity, classes and whether done of `n` points before any is painted: holes, but those
/// `covered` names (valid, class 0, done).
fn unpainted(n: usize, covered: Option<&[bool]>) -> (Vec<bool>, Vec<u8>, Vec<bool>) {
    match covered {
        None => (vec![false; n], vec![HOLE; n], vec![false; n]),
        Some(c) => (
            c.to_vec(),
            c.iter().map(|&c| if c { 0 } else { HOLE }).collect(),
            c.to_vec(),
        ),
    }
}

/// One row of a tile being painted ([`Resampler::paint`]): what each point holds so far, and
/// the positions of those worked out.
struct RowOut<'r> {
    values: &'r mut [i32],
    valid: &'r mut [bool],
    won: &'r mut [u16],
    class: &'r mut [u8],
    done: &'r mut [bool],
    positions: &'r mut Vec<Option<cbdam_codec::geodesy::LatLon>>,
}

/// The points of a row of a tile one input paints: face, the tile's first column `x0`, the
/// row's `y`, the stride's `log2` and the columns (in points of the stride) of its rectangle.
struct Run<'r> {
    face: u8,
    x0: i64,
    y: i64,
    s: u32,
    columns: std::ops::RangeInclusive<usize>,
    /// The input's column of each of `columns` (from its first) where worked out once for
    /// the tile ([`Resampler::input_columns`]), for points inside the face.
    input_columns: Option<&'r [Option<f64>]>,
}

/// A resampled tile and the winning input of each point it holds.
type Held = Arc<(Arc<PlanetTile>, Vec<u16>)>;

/// The lattice's tiles on demand: resampled at the stride the outline fixed (or thinner, as
/// asked), the most recent kept up to a budget of bytes.
pub struct LatticeTiles<'a> {
    resampler: Resampler<'a>,
    /// Per face, per tile: `log2` of the stride it holds its points at.
    strides: Vec<Vec<u32>>,
    cache: Mutex<TileCache>,
    /// Heights measured in place of the lattice's by the resampling error (a decoded surface).
    heights: Mutex<Option<Arc<dyn TileHeights + 'a>>>,
}

/// Heights that [`LatticeTiles::resampling`] measures instead of the lattice's where set
/// ([`LatticeTiles::set_heights`]): `cbdam verify`'s end-to-end error of a decoded planet.
pub trait TileHeights: Send + Sync {
    /// Tile `index` of `face` (the lattice's, at some stride) with these heights and validity
    /// at its points; its rectangle, stride and classes kept.
    fn heights(&self, face: u8, index: usize, tile: &PlanetTile) -> Result<PlanetTile>;
}

/// Recently resampled tiles, by `(face, tile, stride)`, least recently used first in `order`.
struct TileCache {
    held: HashMap<(u8, usize, u32), Held>,
    order: VecDeque<(u8, usize, u32)>,
    bytes: u64,
    budget: u64,
}

impl TileCache {
    /// Lets the least recently used tiles go until the rest fit the budget.
    fn let_go_over_budget(&mut self) {
        while self.bytes > self.budget {
            let Some(old) = self.order.pop_front() else {
                break;
            };
            if let Some(t) = self.held.remove(&old) {
                self.bytes -= tile_bytes(t.0.points());
            }
        }
    }

    /// The tile held under `key`, if any, made the most recently used.
    fn get(&mut self, key: &(u8, usize, u32)) -> Option<Held> {
        let held = Arc::clone(self.held.get(key)?);
        if let Some(at) = self.order.iter().position(|k| k == key) {
            self.order.remove(at);
            self.order.push_back(*key);
        }
        Some(held)
    }
}

/// Bytes a tile of `points` points takes with its winners: height, validity, class, winner.
fn tile_bytes(points: usize) -> u64 {
    points as u64 * (4 + 1 + 1 + 2)
}

impl<'a> LatticeTiles<'a> {
    /// Resamples every tile once (on the current rayon pool, one tile per worker at a time):
    /// the outline of the planet, the stride of every tile, and the distinct lattice points
    /// with data and the points the tiles hold; each tile also put in `apex` where given (what
    /// the apex will read of it, so that the apex paints nothing).
    pub fn outline(
        resampler: Resampler<'a>,
        cache_budget: u64,
        apex: Option<&ApexViewWriter>,
    ) -> Result<(Self, PlanetOutline, u64, u64)> {
        let d = *resampler.domain();
        let per_face = resampler.tiles_per_face();
        let (n, k) = (d.n(), d.layout().k());
        let (t, variable) = (resampler.tile_log2(), resampler.is_variable());
        let empty = || PlanetOutline::new(n, k, t, variable).expect("the resampler's lattice");
        type Part = (PlanetOutline, Vec<(u8, usize, u32)>, u64, u64);
        let (outline, strides, valid, held) = (0..usize::from(d.faces()) * per_face)
            .into_par_iter()
            .try_fold(
                || (empty(), Vec::new(), 0, 0),
                |(mut o, mut s, valid, held): Part, i| -> Result<Part> {
                    let face = (i / per_face) as u8;
                    let keep = apex.map(ApexViewWriter::finest_stride);
                    let tile = resampler.outline_tile(face, i % per_face, keep)?;
                    if let Some(apex) = apex {
                        apex.put(face, i % per_face, &tile)?;
                    }
                    o.add(face, &tile);
                    s.push((face, i % per_face, tile.stride));
                    let v = valid_in_tile(&d, face, &tile);
                    Ok((o, s, valid + v, held + tile.points() as u64))
                },
            )
            .try_reduce(
                || (empty(), Vec::new(), 0, 0),
                |mut a, b| {
                    a.0.merge(b.0);
                    a.1.extend(b.1);
                    Ok((a.0, a.1, a.2 + b.2, a.3 + b.3))
                },
            )?;
        let mut by_tile = vec![vec![0; per_face]; usize::from(d.faces())];
        for (f, i, s) in strides {
            by_tile[usize::from(f)][i] = s;
        }
        let tiles = Self::with_strides(resampler, by_tile, cache_budget)?;
        Ok((tiles, outline, valid, held))
    }

    /// The tiles at the strides an earlier [`LatticeTiles::outline`] of the same resampler
    /// fixed ([`LatticeTiles::strides`]; a sharded build's steps share them).
    pub fn with_strides(
        resampler: Resampler<'a>,
        strides: Vec<Vec<u32>>,
        cache_budget: u64,
    ) -> Result<Self> {
        let faces = usize::from(resampler.domain().faces());
        if strides.len() != faces
            || strides
                .iter()
                .any(|f| f.len() != resampler.tiles_per_face())
        {
            return Err(BuildError::Invalid(format!(
                "tile strides for {} faces of {} tiles, not {faces} of {}",
                strides.len(),
                strides.first().map_or(0, Vec::len),
                resampler.tiles_per_face()
            )));
        }
        Ok(Self {
            resampler,
            strides,
            cache: Mutex::new(TileCache {
                held: HashMap::new(),
                order: VecDeque::new(),
                bytes: 0,
                budget: cache_budget,
            }),
            heights: Mutex::new(None),
        })
    }

    /// Takes `diamonds` bytes — what a build or a verify holds for the planet's diamonds, which
    /// grows with its records, not with its blocks — half from this cache (the oldest tiles let
    /// go) and half from the blocks' `block_bytes`: what the blocks may hold now.
    pub fn share_out(&self, diamonds: u64, block_bytes: u64) -> u64 {
        let mut cache = self.cache.lock().expect("the tile cache");
        cache.budget = cache.budget.saturating_sub(diamonds / 2);
        cache.let_go_over_budget();
        block_bytes.saturating_sub(diamonds - diamonds / 2)
    }

    /// Measures `heights` instead of the lattice's heights from now on (`None`: the lattice's).
    pub fn set_heights(&self, heights: Option<Arc<dyn TileHeights + 'a>>) {
        *self.heights.lock().expect("the heights measured") = heights;
    }

    /// `tile` (tile `index` of `face`) with the heights measured ([`Self::set_heights`]).
    fn measured(&self, face: u8, index: usize, tile: &Arc<PlanetTile>) -> Result<Arc<PlanetTile>> {
        let heights = self.heights.lock().expect("the heights measured").clone();
        match heights {
            None => Ok(Arc::clone(tile)),
            Some(h) => Ok(Arc::new(h.heights(face, index, tile)?)),
        }
    }

    /// Per face, per tile: `log2` of the stride it holds its points at.
    pub fn strides(&self) -> &[Vec<u32>] {
        &self.strides
    }

    /// `log2` of the tiles' side.
    pub fn tile_log2(&self) -> u32 {
        self.resampler.tile_log2()
    }

    /// Input `input`'s resampling error, over the tiles it can cover: where its samples lie on
    /// one face, on the parts of those tiles around them held at once; else a band of its rows
    /// at a time ([`resampling_bands`]), so that a global input does not hold the lattice.
    pub fn resampling(&self, input: usize) -> Result<InputResampling> {
        let r = &self.resampler;
        match sample_footprint(&r.inputs.inputs[input], r.strides[input], r.side) {
            Some(parts) => self.resampling_of_inset(input, &parts),
            None => self.resampling_in_bands(input),
        }
    }

    /// Tile `index` of `face` on multiples of `2^max(s, min(min_stride, tile side))` for its
    /// own stride `2^s`, with its points' winners.
    fn held(&self, face: u8, index: usize, min_stride: u32) -> Result<Held> {
        let own = self.strides[usize::from(face)][index];
        let stride = own.max(min_stride.min(self.resampler.tile_log2()));
        let key = (face, index, stride);
        if let Some(t) = self.cache.lock().expect("the tile cache").get(&key) {
            return Ok(t);
        }
        let (tile, won) = self.resampler.tile(face, index, stride)?;
        let held: Held = Arc::new((Arc::new(tile), won));
        let mut cache = self.cache.lock().expect("the tile cache");
        let bytes = tile_bytes(held.0.points());
        if bytes <= cache.budget && cache.held.insert(key, Arc::clone(&held)).is_none() {
            cache.bytes += bytes;
            cache.order.push_back(key);
            cache.let_go_over_budget();
        }
        Ok(held)
    }

    /// `log2` of the stride [`LatticeTiles::held`] holds tile `index` of `face` at for
    /// `min_stride`: its own, or `min_stride` (at most the tile's side) where coarser.
    fn view_stride(&self, face: u8, index: usize, min_stride: u32) -> u32 {
        let own = self.strides[usize::from(face)][index];
        own.max(min_stride.min(self.resampler.tile_log2()))
    }

    /// Tile `index` of `face` as [`LatticeTiles::held`] gives it, or, where the cache does not
    /// hold it and `part` is given, with only the points in `part` painted (not kept).
    fn held_part(
        &self,
        face: u8,
        index: usize,
        min_stride: u32,
        part: Option<Rect>,
    ) -> Result<Held> {
        let Some(part) = part else {
            return self.held(face, index, min_stride);
        };
        let stride = self.view_stride(face, index, min_stride);
        if let Some(t) = self
            .cache
            .lock()
            .expect("the tile cache")
            .get(&(face, index, stride))
        {
            return Ok(t);
        }
        let (tile, won) = self.resampler.tile_part(face, index, stride, part)?;
        Ok(Arc::new((Arc::new(tile), won)))
    }

    /// Input `input`'s share of the lattice for its resampling error: `tiles` (those it can
    /// cover, [`LatticeTiles::input_tiles_in`]), thinned to its stride (the lattice points its
    /// samples are compared with), the others empty; of a tile given with a part, only the
    /// points in that part are painted.
    fn input_view(&self, input: usize, tiles: Vec<(u8, usize, Option<Rect>)>) -> Result<Resampled> {
        let r = &self.resampler;
        let d = r.domain();
        let stride = r.strides[input];
        let held = tiles
            .into_par_iter()
            .map(|(f, i, part)| Ok(((f, i), self.held_part(f, i, stride, part)?)))
            .collect::<Result<HashMap<_, _>>>()?;
        let mut winners = vec![vec![Vec::new(); r.tiles_per_face()]; usize::from(d.faces())];
        let mut tiles = HashMap::new();
        for ((f, i), h) in held {
            winners[usize::from(f)][i] = h.1.clone();
            tiles.insert((f, i), self.measured(f, i, &h.0)?);
        }
        let planet = PlanetGrid::partial(d.n(), d.layout().k(), r.tile_log2, r.variable, tiles)?;
        Ok(Resampled {
            planet,
            winners,
            strides: r.strides.clone(),
        })
    }

    /// The tiles input `input` can cover, each with the part of it around the input's samples
    /// where they lie on at most three faces ([`sample_footprint`]), else whole (`None`).
    fn input_tiles(&self, input: usize) -> Vec<(u8, usize, Option<Rect>)> {
        let r = &self.resampler;
        let footprint = sample_footprint(&r.inputs.inputs[input], r.strides[input], r.side);
        self.input_tiles_in(input, footprint.as_deref())
    }

    /// [`LatticeTiles::input_tiles`] for the samples whose footprint is `footprint` (`None`:
    /// every tile the input can cover, whole).
    fn input_tiles_in(
        &self,
        input: usize,
        footprint: Option<&[(u8, Rect)]>,
    ) -> Vec<(u8, usize, Option<Rect>)> {
        let r = &self.resampler;
        let d = r.domain();
        (0..d.faces())
            .flat_map(|f| (0..r.tiles_per_face()).map(move |i| (f, i)))
            .filter(|&(f, i)| {
                r.tiles
                    .candidates(f, i)
                    .any(|(c, _)| usize::from(c) == input)
            })
            .filter_map(|(f, i)| match footprint {
                None => Some((f, i, None)),
                Some(parts) => {
                    let (x0, y0, x1, y1) = r.rects[i];
                    let meets = |p: &Rect| x0 <= p.2 && p.0 <= x1 && y0 <= p.3 && p.1 <= y1;
                    parts
                        .iter()
                        .find(|(face, part)| *face == f && meets(part))
                        .map(|&(_, part)| (f, i, Some(part)))
                }
            })
            .collect()
    }
}

impl PlanetTiles for LatticeTiles<'_> {
    fn tile(
        &self,
        face: u8,
        index: usize,
        min_stride: u32,
    ) -> std::result::Result<Arc<PlanetTile>, CodecError> {
        self.held(face, index, min_stride)
            .map(|h| Arc::clone(&h.0))
            .map_err(|e| CodecError::invalid(format!("resampling face {face} tile {index}: {e:#}")))
    }

    /// The tile whole where the cache holds it, else only `part` painted (not kept).
    fn tile_part(
        &self,
        face: u8,
        index: usize,
        part: Rect,
    ) -> std::result::Result<Arc<PlanetTile>, CodecError> {
        let own = self.strides[usize::from(face)][index];
        let key = (face, index, own);
        if let Some(t) = self.cache.lock().expect("the tile cache").get(&key) {
            return Ok(Arc::clone(&t.0));
        }
        self.resampler
            .tile_part(face, index, own, part)
            .map(|(tile, _)| Arc::new(tile))
            .map_err(|e| CodecError::invalid(format!("resampling face {face} tile {index}: {e:#}")))
    }
}

#[path = "planet_lattice_encode.rs"]
mod encode;
pub use encode::{LatticeEncode, encode_out_of_core};

#[path = "planet_resampling_bands.rs"]
mod resampling_bands;

#[path = "planet_lattice_covered.rs"]
mod covered;

#[cfg(test)]
#[path = "planet_lattice_tests.rs"]
mod tests;
