//! The input of a planet: six faces of integer heights on a cube-sphere's lattice, held in
//! tiles — every lattice point where fine data is, every `2^s`-th where only coarser data is.

use std::collections::HashMap;
use std::sync::Arc;

use rayon::prelude::*;

use crate::CodecError;
use crate::geometry::{Domain, FacePoint};
use crate::hierarchy::Resolution;
use crate::hierarchy::resolution::{COARSE_ONLY, HOLE};
use crate::quant::HeightGrid;

/// `log2` of the smallest tile side, in lattice steps (a face narrower than that is one tile).
pub const TILE_MIN_LOG2: u32 = 10;

/// Tiles along a face side at most (the tile side grows with the face beyond
/// `2^TILE_MIN_LOG2 · MAX_TILES_ACROSS` steps), so that a planet has at most
/// `6 · MAX_TILES_ACROSS²` tiles.
pub const MAX_TILES_ACROSS: i64 = 128;

/// `log2` of the tile side for a face of `side` lattice steps: at least
/// [`TILE_MIN_LOG2`], at most [`MAX_TILES_ACROSS`] tiles across, and never wider than the face.
pub fn tile_log2(side: i64) -> u32 {
    let face = 63 - side.max(1).leading_zeros();
    let across = 63 - MAX_TILES_ACROSS.leading_zeros();
    TILE_MIN_LOG2.max(face.saturating_sub(across)).min(face)
}

/// One tile of a face: the lattice points `x0..=x1 × y0..=y1` on multiples of `2^stride`
/// (a tile's rectangle is closed: neighbouring tiles both hold the points of their common
/// side, with the same values).
#[derive(Clone, Debug, PartialEq)]
pub struct PlanetTile {
    /// `log2` of the spacing of the points held: 0 where fine data is.
    pub stride: u32,
    /// `(x0, y0, x1, y1)`, inclusive, in the face's lattice.
    pub rect: (i64, i64, i64, i64),
    /// The points held, `((x1 − x0) >> stride) + 1` wide.
    pub grid: HeightGrid,
    /// Their resolution classes ([`Resolution`]) on a variable-resolution planet.
    pub class: Option<Vec<u8>>,
    /// Largest `|value|` of a valid point, and whether every point held is valid.
    max_abs: i64,
    all_valid: bool,
}

impl PlanetTile {
    /// A tile of `grid`'s points (and `class`es) on multiples of `2^stride` over `rect`.
    /// Errors if the sizes disagree or the rectangle's corners are not on the stride.
    pub fn new(
        stride: u32,
        rect: (i64, i64, i64, i64),
        grid: HeightGrid,
        class: Option<Vec<u8>>,
    ) -> Result<Self, CodecError> {
        let (x0, y0, x1, y1) = rect;
        let step = 1i64 << stride;
        let aligned = [x0, y0, x1, y1].iter().all(|v| v % step == 0);
        if stride >= 32 || !aligned || x1 < x0 || y1 < y0 {
            return Err(CodecError::invalid(format!(
                "a tile over {rect:?} at stride 2^{stride}: corners must lie on the stride"
            )));
        }
        let (w, h) = (
            ((x1 - x0) >> stride) as usize + 1,
            ((y1 - y0) >> stride) as usize + 1,
        );
        if (grid.width, grid.height) != (w, h)
            || grid.values.len() != w * h
            || grid.valid.len() != w * h
            || class.as_ref().is_some_and(|c| c.len() != w * h)
        {
            return Err(CodecError::invalid(format!(
                "a tile over {rect:?} at stride 2^{stride} holds {w}×{h} points, not {}×{}",
                grid.width, grid.height
            )));
        }
        if let Some(class) = &class {
            let agree = class
                .iter()
                .zip(grid.valid.iter())
                .all(|(&c, &v)| (c < 32) == v && (c < 32 || c == COARSE_ONLY || c == HOLE));
            if !agree {
                return Err(CodecError::invalid(format!(
                    "a tile over {rect:?}: resolution classes disagree with its valid points"
                )));
            }
        }
        let max_abs = grid
            .range()
            .map_or(0, |(lo, hi)| i64::from(lo).abs().max(i64::from(hi).abs()));
        let all_valid = !grid.has_invalid();
        Ok(Self {
            stride,
            rect,
            grid,
            class,
            max_abs,
            all_valid,
        })
    }

    /// The index of lattice point `(x, y)` of the face among the points held, `None` when it
    /// is outside the tile or between the stride's points.
    #[inline]
    pub fn index(&self, x: i64, y: i64) -> Option<usize> {
        let (x0, y0, x1, y1) = self.rect;
        let mask = (1i64 << self.stride) - 1;
        let inside = (x0..=x1).contains(&x) && (y0..=y1).contains(&y);
        (inside && (x - x0) & mask == 0 && (y - y0) & mask == 0).then(|| {
            ((y - y0) >> self.stride) as usize * self.grid.width
                + ((x - x0) >> self.stride) as usize
        })
    }

    /// Largest `|value|` of a valid point held, and whether every point held is valid.
    pub fn bounds(&self) -> (i64, bool) {
        (self.max_abs, self.all_valid)
    }

    /// Whether the point held at `k` is drawn: a sample, or coarse only.
    #[inline]
    fn drawn_at(&self, k: usize) -> bool {
        match &self.class {
            Some(class) => class[k] != HOLE,
            None => self.grid.valid[k],
        }
    }

    /// Points held.
    pub fn points(&self) -> usize {
        self.grid.width * self.grid.height
    }
}

/// The tiles of a partial planet by face and index, and the empty tile read everywhere else.
type SparseTiles = (HashMap<(u8, usize), Arc<PlanetTile>>, Arc<PlanetTile>);

/// Integer heights (and validity) at the lattice points of the six faces of a cube-sphere
/// (`Domain::cube_sphere(n, k)`), `S = (N − 1)·2^K` steps per face side, in square tiles of
/// `2^tile_log2(S)` steps ([`PlanetTile`]). A tile holds every point where some input is as
/// fine as the lattice, and only the points on multiples of `2^s` where the finest data around
/// has stride `2^s` (variable resolution): the memory follows the data, not the lattice, so a
/// 3″ inset in a 5′ planet costs what the inset and the 5′ data are worth.
///
/// A point on a cube edge or corner lies on two or three faces; every face holding it holds
/// the same value and validity, and reads go through its canonical point
/// ([`Domain::canonical_point`]), so they agree by construction.
///
/// A variable-resolution planet ([`PlanetGrid::with_classes`]) also says, per point held, what
/// the point is ([`Resolution`]): a sample of an input of stride `2^j` (a vertex of level
/// `L − 2j`, constrained from that level on), *coarse only* (between a coarser input's
/// samples: drawn, not constrained, so the hierarchy stops at that input's level there) or a
/// hole. A point between the points a tile holds is coarse only when the corners of its cell
/// of held points are all drawn, a hole otherwise.
#[derive(Clone, Debug, PartialEq)]
pub struct PlanetGrid {
    domain: Domain,
    tile_log2: u32,
    tiles_across: usize,
    faces: Vec<Vec<Arc<PlanetTile>>>,
    variable: bool,
    /// A partial planet ([`PlanetGrid::partial`]): its tiles by face and index, and the empty
    /// tile read everywhere else (`faces` then holds no tile).
    sparse: Option<Arc<SparseTiles>>,
}

impl PlanetGrid {
    /// The planet whose faces are `faces` (face `f` at index `f`), every point held. Errors if
    /// there are not six faces of `(S + 1)²` points, or if two faces disagree on a shared edge
    /// or corner point.
    pub fn new(n: usize, k: u32, faces: Vec<HeightGrid>) -> Result<Self, CodecError> {
        let domain = Domain::cube_sphere(n, k)?;
        let cube = *domain.cube().expect("a cube-sphere has a cube");
        let side = cube.side();
        let points = side as usize + 1;
        if faces.len() != usize::from(domain.faces()) {
            return Err(CodecError::invalid(format!(
                "a planet has 6 faces, not {}",
                faces.len()
            )));
        }
        for (f, g) in faces.iter().enumerate() {
            if (g.width, g.height) != (points, points)
                || g.values.len() != points * points
                || g.valid.len() != points * points
            {
                return Err(CodecError::invalid(format!(
                    "face {f} is {}×{} samples; a cube-sphere face of N = {n}, K = {k} has \
                     {points}×{points}",
                    g.width, g.height
                )));
            }
        }
        let value = |p: FacePoint| faces[usize::from(p.face)].get(p.x, p.y);
        for face in 0..domain.faces() {
            for p in boundary(face, side) {
                let (reps, len) = cube.representations(p);
                for r in &reps[1..len] {
                    if value(p) != value(*r) {
                        let show =
                            |v: Option<i32>| v.map_or("nodata".to_string(), |v| v.to_string());
                        return Err(CodecError::invalid(format!(
                            "face {} ({}, {}) holds {} but face {} ({}, {}), the same point of \
                             a cube edge, holds {}: shared points must hold one value",
                            p.face,
                            p.x,
                            p.y,
                            show(value(p)),
                            r.face,
                            r.x,
                            r.y,
                            show(value(*r))
                        )));
                    }
                }
            }
        }
        let tile_log2 = tile_log2(side);
        let faces = faces
            .iter()
            .map(|g| {
                tile_rects(side, tile_log2)
                    .into_iter()
                    .map(|rect| {
                        PlanetTile::new(
                            0,
                            rect,
                            window(g, rect, |g, k| (g.values[k], g.valid[k])),
                            None,
                        )
                        .map(Arc::new)
                    })
                    .collect::<Result<Vec<_>, _>>()
            })
            .collect::<Result<Vec<_>, _>>()?;
        Ok(Self {
            domain,
            tile_log2,
            tiles_across: tiles_across(side, tile_log2),
            faces,
            variable: false,
            sparse: None,
        })
    }

    /// A planet of the given tiles of `2^tile_log2` steps ([`tile_log2`] is what a build
    /// uses): `faces[f]` are face `f`'s tiles in row-major order ([`PlanetGrid::tile_rects`]),
    /// each at its own stride. `variable`: every tile carries resolution classes. The caller
    /// computes every shared edge point from its canonical point (reads go through it anyway);
    /// errors if the tiles do not cut the faces as [`PlanetGrid::tile_rects`] says, or a
    /// stride is wider than a tile.
    pub fn from_tiles(
        n: usize,
        k: u32,
        tile_log2: u32,
        faces: Vec<Vec<PlanetTile>>,
        variable: bool,
    ) -> Result<Self, CodecError> {
        let domain = Domain::cube_sphere(n, k)?;
        let side = domain.cube().expect("a cube-sphere has a cube").side();
        if tile_log2 >= 32 {
            return Err(CodecError::invalid(format!(
                "tiles of 2^{tile_log2} lattice steps"
            )));
        }
        let rects = tile_rects(side, tile_log2);
        if faces.len() != usize::from(domain.faces()) {
            return Err(CodecError::invalid(format!(
                "a planet has 6 faces, not {}",
                faces.len()
            )));
        }
        for (f, tiles) in faces.iter().enumerate() {
            if tiles.len() != rects.len() {
                return Err(CodecError::invalid(format!(
                    "face {f} has {} tiles, not {}",
                    tiles.len(),
                    rects.len()
                )));
            }
            for (t, r) in tiles.iter().zip(&rects) {
                if t.rect != *r || t.stride > tile_log2 || t.class.is_some() != variable {
                    return Err(CodecError::invalid(format!(
                        "face {f}: a tile over {:?} at stride 2^{} where the tiling has {r:?}{}",
                        t.rect,
                        t.stride,
                        if t.class.is_some() != variable {
                            ", with classes on some tiles only"
                        } else {
                            ""
                        }
                    )));
                }
            }
        }
        let faces = faces
            .into_iter()
            .map(|tiles| tiles.into_iter().map(Arc::new).collect())
            .collect();
        Ok(Self {
            domain,
            tile_log2,
            tiles_across: tiles_across(side, tile_log2),
            faces,
            variable,
            sparse: None,
        })
    }

    /// A planet of which only some tiles are held (`held`, by face and index among
    /// [`PlanetGrid::tile_rects`]), for code that reads only their points (a block of a
    /// block-wise encode, [`super::PlanetBlocks`]): every other tile holds no point, so reads
    /// there say nodata — the caller must not read there. Errors as
    /// [`PlanetGrid::from_tiles`] does on a held tile.
    pub fn partial(
        n: usize,
        k: u32,
        tile_log2: u32,
        variable: bool,
        held: HashMap<(u8, usize), Arc<PlanetTile>>,
    ) -> Result<Self, CodecError> {
        let domain = Domain::cube_sphere(n, k)?;
        let side = domain.cube().expect("a cube-sphere has a cube").side();
        let rects = tile_rects(side, tile_log2);
        let absent = Arc::new(PlanetTile::new(
            0,
            (-1, -1, -1, -1),
            HeightGrid {
                width: 1,
                height: 1,
                values: vec![0].into(),
                valid: vec![false].into(),
            },
            variable.then(|| vec![HOLE]),
        )?);
        for (&(f, i), t) in &held {
            let Some(r) = rects.get(i).filter(|_| f < domain.faces()) else {
                return Err(CodecError::invalid(format!(
                    "face {f} tile {i}: the planet has 6 faces of {} tiles",
                    rects.len()
                )));
            };
            if t.rect != *r || t.stride > tile_log2 || t.class.is_some() != variable {
                return Err(CodecError::invalid(format!(
                    "face {f}: a tile over {:?} at stride 2^{} where the tiling has {r:?}",
                    t.rect, t.stride
                )));
            }
        }
        Ok(Self {
            domain,
            tile_log2,
            tiles_across: tiles_across(side, tile_log2),
            faces: vec![Vec::new(); usize::from(domain.faces())],
            variable,
            sparse: Some(Arc::new((held, absent))),
        })
    }

    /// Whether the planet carries resolution classes ([`PlanetGrid::with_classes`]).
    pub fn is_variable(&self) -> bool {
        self.variable
    }

    /// The rectangles of tiles of `2^tile_log2` steps on every face of `domain`, row-major:
    /// what [`PlanetGrid::from_tiles`] takes.
    pub fn tile_rects(domain: &Domain, tile_log2: u32) -> Vec<(i64, i64, i64, i64)> {
        let side = domain.cube().map_or(0, |c| c.side());
        tile_rects(side, tile_log2)
    }

    /// The same planet at variable resolution: `classes[f]` classifies face `f`'s points
    /// ([`Resolution`], row-major, every point of the face). Errors if a face's classes do not
    /// match its grid (samples exactly where it is valid) or two faces classify a shared edge
    /// or corner point differently, or if the planet does not hold every point.
    pub fn with_classes(self, classes: Vec<Resolution>) -> Result<Self, CodecError> {
        if classes.len() != self.faces.len() {
            return Err(CodecError::invalid(format!(
                "{} faces of classes for a planet of {} faces",
                classes.len(),
                self.faces.len()
            )));
        }
        let cube = *self.domain.cube().expect("a cube-sphere has a cube");
        let side = cube.side();
        let points = side as usize + 1;
        if self.faces.iter().flatten().any(|t| t.stride != 0) {
            return Err(CodecError::invalid(
                "classes are given for every lattice point: the planet must hold every point",
            ));
        }
        for (f, c) in classes.iter().enumerate() {
            c.check(&self.face_grid(f as u8))
                .map_err(|e| CodecError::invalid(format!("face {f}: {e}")))?;
        }
        let class =
            |p: FacePoint| classes[usize::from(p.face)].class[p.y as usize * points + p.x as usize];
        for face in 0..self.domain.faces() {
            for p in boundary(face, side) {
                let (reps, len) = cube.representations(p);
                if let Some(r) = reps[1..len].iter().find(|r| class(**r) != class(p)) {
                    return Err(CodecError::invalid(format!(
                        "face {} ({}, {}) and face {} ({}, {}), the same point of a cube edge, \
                         have different resolution classes ({} and {})",
                        p.face,
                        p.x,
                        p.y,
                        r.face,
                        r.x,
                        r.y,
                        class(p),
                        class(*r)
                    )));
                }
            }
        }
        let mut faces = self.faces;
        for (tiles, c) in faces.iter_mut().zip(&classes) {
            for t in tiles.iter_mut() {
                let t = Arc::make_mut(t);
                let (x0, y0, x1, y1) = t.rect;
                let mut held = Vec::with_capacity(t.points());
                for y in y0..=y1 {
                    let row = y as usize * points;
                    held.extend_from_slice(&c.class[row + x0 as usize..=row + x1 as usize]);
                }
                t.class = Some(held);
            }
        }
        Ok(Self {
            faces,
            variable: true,
            ..self
        })
    }

    /// The planet whose height at every lattice point is `height` of the point's canonical
    /// coordinates ([`Domain::canonical_point`]; `None`: nodata), so shared edge and corner
    /// points are computed once.
    pub fn from_fn(
        n: usize,
        k: u32,
        height: impl Fn(FacePoint) -> Option<i32> + Sync,
    ) -> Result<Self, CodecError> {
        let domain = Domain::cube_sphere(n, k)?;
        let points = domain.cube().expect("a cube-sphere has a cube").side() as usize + 1;
        let faces = (0..domain.faces())
            .map(|face| {
                let samples: Vec<Option<i32>> = (0..points * points)
                    .into_par_iter()
                    .map(|k| {
                        let (x, y) = ((k % points) as i64, (k / points) as i64);
                        let c = domain
                            .canonical_point(face, x, y)
                            .expect("a point of the face square is on the surface");
                        height(c)
                    })
                    .collect();
                HeightGrid {
                    width: points,
                    height: points,
                    values: samples.iter().map(|v| v.unwrap_or(0)).collect(),
                    valid: samples.iter().map(Option::is_some).collect(),
                }
            })
            .collect();
        Self::new(n, k, faces)
    }

    /// The cube-sphere the grids cover.
    pub fn domain(&self) -> &Domain {
        &self.domain
    }

    /// The tiles of face `face`, row-major.
    ///
    /// # Panics
    /// If `face` is not a face (≥ 6).
    pub fn tiles(&self, face: u8) -> &[Arc<PlanetTile>] {
        &self.faces[usize::from(face)]
    }

    /// Tile `index` of face `face` (on a partial planet, an empty tile where none is held).
    ///
    /// # Panics
    /// If there is no such tile.
    #[inline]
    pub fn tile(&self, face: u8, index: usize) -> &Arc<PlanetTile> {
        match &self.sparse {
            None => &self.faces[usize::from(face)][index],
            Some(sparse) => sparse.0.get(&(face, index)).unwrap_or(&sparse.1),
        }
    }

    /// `log2` of the tiles' side in lattice steps.
    pub fn tile_log2(&self) -> u32 {
        self.tile_log2
    }

    /// The index among [`PlanetGrid::tiles`] of the tile that owns lattice point `(x, y)` of
    /// a face (`0 ≤ x, y ≤ S`): the one starting at or before it (the last one for `S`).
    #[inline]
    pub fn tile_index(&self, x: i64, y: i64) -> usize {
        let (bx, by) = tile_cell(self.tiles_across, self.tile_log2, x, y);
        by * self.tiles_across + bx
    }

    /// The indices of the tiles whose rectangles meet `(x0, y0, x1, y1)` (clipped to the
    /// face).
    pub fn tiles_meeting(
        &self,
        (x0, y0, x1, y1): (i64, i64, i64, i64),
    ) -> impl Iterator<Item = usize> + '_ {
        let side = self.domain.cube().expect("a cube-sphere").side();
        tiles_meeting(side, self.tile_log2, (x0, y0, x1, y1))
    }

    /// The tile and index of lattice point `(x, y)` of `face` (inside the face, `0 ≤ x, y ≤
    /// S`) among the points that tile holds; `None` between its points.
    #[inline]
    pub fn held(&self, face: u8, x: i64, y: i64) -> Option<(&PlanetTile, usize)> {
        let t: &PlanetTile = self.tile(face, self.tile_index(x, y));
        t.index(x, y).map(|k| (t, k))
    }

    /// The height at lattice point `(x, y)` of `face`'s frame — a point of the face or one past
    /// one of its edges (read on the face holding it) — or `None` at nodata, between the points
    /// held or off the surface.
    #[inline]
    pub fn get(&self, face: u8, x: i64, y: i64) -> Option<i32> {
        let c = self.domain.canonical_point(face, x, y)?;
        let (t, k) = self.held(c.face, c.x, c.y)?;
        t.grid.valid[k].then(|| t.grid.values[k])
    }

    /// Whether `(x, y)` of `face`'s frame (as for [`PlanetGrid::get`]) has data; `None` off the
    /// surface.
    #[inline]
    pub fn validity(&self, face: u8, x: i64, y: i64) -> Option<bool> {
        let c = self.domain.canonical_point(face, x, y)?;
        Some(
            self.held(c.face, c.x, c.y)
                .is_some_and(|(t, k)| t.grid.valid[k]),
        )
    }

    /// Face `face` as one grid of every lattice point (points between those held are invalid).
    /// For small planets (tests, whole-face comparisons).
    pub fn face_grid(&self, face: u8) -> HeightGrid {
        let side = self.domain.cube().expect("a cube-sphere").side();
        let points = side as usize + 1;
        let mut values = vec![0; points * points];
        let mut valid = vec![false; points * points];
        for t in self.tiles(face) {
            let (x0, y0, x1, y1) = t.rect;
            let step = 1usize << t.stride;
            for (j, y) in (y0..=y1).step_by(step).enumerate() {
                for (i, x) in (x0..=x1).step_by(step).enumerate() {
                    let k = j * t.grid.width + i;
                    let at = y as usize * points + x as usize;
                    values[at] = t.grid.values[k];
                    valid[at] = t.grid.valid[k];
                }
            }
        }
        HeightGrid {
            width: points,
            height: points,
            values: values.into(),
            valid: valid.into(),
        }
    }

    /// Whether `(x, y)` of `face`'s frame (as for [`PlanetGrid::get`]) is drawn: a sample, or
    /// coarse only on a variable-resolution planet (what the nodata mask records); `None` off
    /// the surface. Between the points a tile holds: whether the corners of its cell are all
    /// drawn.
    #[inline]
    pub fn drawn(&self, face: u8, x: i64, y: i64) -> Option<bool> {
        let c = self.domain.canonical_point(face, x, y)?;
        let t = self.tile(c.face, self.tile_index(c.x, c.y));
        if let Some(k) = t.index(c.x, c.y) {
            return Some(t.drawn_at(k));
        }
        let step = 1i64 << t.stride;
        let (x0, y0, _, _) = t.rect;
        let around = |v: i64, o: i64| {
            let lo = o + ((v - o) & !(step - 1));
            if lo == v { [v, v] } else { [lo, lo + step] }
        };
        let xs = around(c.x, x0);
        let ys = around(c.y, y0);
        Some(ys.iter().all(|&y| {
            xs.iter()
                .all(|&x| t.index(x, y).is_some_and(|k| t.drawn_at(k)))
        }))
    }

    /// Whether some point is not drawn (no data at all): the hierarchy then carries a nodata
    /// mask.
    pub fn has_nodata(&self) -> bool {
        self.faces.iter().flatten().any(|t| match &t.class {
            Some(class) => class.contains(&HOLE),
            None => !t.all_valid,
        })
    }

    /// Smallest and largest valid height, `None` when no point has data.
    pub fn range(&self) -> Option<(i32, i32)> {
        self.faces
            .iter()
            .flatten()
            .filter_map(|t| t.grid.range())
            .reduce(|a, b| (a.0.min(b.0), a.1.max(b.1)))
    }

    /// Distinct lattice points of the surface: `6·S² + 2` (edge and corner points once).
    pub fn lattice_points(&self) -> u64 {
        self.domain.lattice_points()
    }

    /// Points the tiles hold (points on tile sides and face edges counted on every tile
    /// holding them): what the planet costs in memory.
    pub fn held_points(&self) -> u64 {
        self.faces.iter().flatten().map(|t| t.points() as u64).sum()
    }

    /// A planet of the same tiles with every point held invalid (0): what
    /// [`PlanetGrid::set`] fills.
    pub fn blank_like(&self) -> Self {
        let faces = self
            .faces
            .iter()
            .map(|tiles| {
                tiles
                    .iter()
                    .map(|t| {
                        let p = t.points();
                        Arc::new(PlanetTile {
                            grid: HeightGrid {
                                width: t.grid.width,
                                height: t.grid.height,
                                values: vec![0; p].into(),
                                valid: vec![false; p].into(),
                            },
                            class: None,
                            max_abs: 0,
                            all_valid: false,
                            ..**t
                        })
                    })
                    .collect()
            })
            .collect();
        Self {
            domain: self.domain,
            tile_log2: self.tile_log2,
            tiles_across: self.tiles_across,
            faces,
            variable: false,
            sparse: self.sparse.clone(),
        }
    }

    /// Sets lattice point `(x, y)` of `face` (inside the face) on every tile of that face
    /// holding it; a point no tile holds is left alone. The tiles' bounds are not updated:
    /// for planets read back, not encoded.
    pub fn set(&mut self, face: u8, x: i64, y: i64, value: i32, valid: bool) {
        let tiles = &mut self.faces[usize::from(face)];
        let across = self.tiles_across;
        let (bx, by) = tile_cell(across, self.tile_log2, x, y);
        // The owner, and the tiles before it along each axis when the point is on their side.
        for (dx, dy) in [(0, 0), (1, 0), (0, 1), (1, 1)] {
            let (Some(tx), Some(ty)) = (bx.checked_sub(dx), by.checked_sub(dy)) else {
                continue;
            };
            let t = &mut tiles[ty * across + tx];
            if let Some(k) = t.index(x, y) {
                let t = Arc::make_mut(t);
                t.grid.values[k] = value;
                t.grid.valid[k] = valid;
            }
        }
    }
}

/// The row-major index of the tile of `2^log2` steps that owns lattice point `(x, y)` of a face
/// of `side` steps (`0 ≤ x, y ≤ side`): what [`PlanetGrid::tile_index`] says of a planet cut so,
/// for code that plans the tiles before they exist.
pub fn tile_of(side: i64, log2: u32, x: i64, y: i64) -> usize {
    let across = tiles_across(side, log2);
    let (bx, by) = tile_cell(across, log2, x, y);
    by * across + bx
}

/// The row-major indices of the tiles of `2^log2` steps, on a face of `side` steps, whose
/// closed rectangles meet `(x0, y0, x1, y1)` (clipped to the face; none when it misses it).
pub fn tiles_meeting(
    side: i64,
    log2: u32,
    (x0, y0, x1, y1): (i64, i64, i64, i64),
) -> impl Iterator<Item = usize> {
    let clip = |v: i64| v.clamp(0, side);
    let misses = x1 < 0 || y1 < 0 || x0 > side || y0 > side || x1 < x0 || y1 < y0;
    let (x0, y0, x1, y1) = (clip(x0), clip(y0), clip(x1), clip(y1));
    let across = tiles_across(side, log2);
    let last = across as i64 - 1;
    // A point on a tile's first row or column also lies on the previous tile's last.
    let first = move |v: i64| (((v - 1).max(0)) >> log2).min(last);
    let end = move |v: i64| (v >> log2).min(last);
    let t = 1i64 << log2;
    let rows = (first(y0)..=end(y1)).filter(move |_| !misses);
    rows.flat_map(move |by| (first(x0)..=end(x1)).map(move |bx| (bx, by)))
        .filter(move |&(bx, by)| {
            let (a0, b0) = (bx * t, by * t);
            let (a1, b1) = (((bx + 1) * t).min(side), ((by + 1) * t).min(side));
            a0 <= x1 && x0 <= a1 && b0 <= y1 && y0 <= b1
        })
        .map(move |(bx, by)| by as usize * across + bx as usize)
}

/// Column and row of the tile owning `(x, y)`: the one starting at or before it, the last one
/// for the face's far side.
#[inline]
fn tile_cell(across: usize, log2: u32, x: i64, y: i64) -> (usize, usize) {
    let last = across - 1;
    (
        ((x >> log2) as usize).min(last),
        ((y >> log2) as usize).min(last),
    )
}

/// Tiles along a face side of `side` steps in tiles of `2^log2`.
pub(super) fn tiles_across(side: i64, log2: u32) -> usize {
    ((side + (1i64 << log2) - 1) >> log2).max(1) as usize
}

/// The closed rectangles of the tiles of a face, row-major.
fn tile_rects(side: i64, log2: u32) -> Vec<(i64, i64, i64, i64)> {
    let across = tiles_across(side, log2) as i64;
    let t = 1i64 << log2;
    (0..across)
        .flat_map(|by| {
            (0..across).map(move |bx| {
                (
                    bx * t,
                    by * t,
                    ((bx + 1) * t).min(side),
                    ((by + 1) * t).min(side),
                )
            })
        })
        .collect()
}

/// The points of `rect` of a whole-face grid `g`, as a grid of their own.
fn window(
    g: &HeightGrid,
    (x0, y0, x1, y1): (i64, i64, i64, i64),
    at: impl Fn(&HeightGrid, usize) -> (i32, bool),
) -> HeightGrid {
    let (w, h) = ((x1 - x0) as usize + 1, (y1 - y0) as usize + 1);
    let mut values = Vec::with_capacity(w * h);
    let mut valid = Vec::with_capacity(w * h);
    for y in y0..=y1 {
        for x in x0..=x1 {
            let (v, ok) = at(g, y as usize * g.width + x as usize);
            values.push(v);
            valid.push(ok);
        }
    }
    HeightGrid {
        width: w,
        height: h,
        values: values.into(),
        valid: valid.into(),
    }
}

/// The points on the boundary of face `face`'s square `[0, side]²` (corners twice).
fn boundary(face: u8, side: i64) -> impl Iterator<Item = FacePoint> {
    (0..=side).flat_map(move |t| {
        [(t, 0), (t, side), (0, t), (side, t)].map(|(x, y)| FacePoint::new(face, x, y))
    })
}
