//! A planet encoded block by block (`encode_planet_in_blocks`: an apex, then one block per tile,
//! each reading only the tiles under its diamonds) is the planet encoded whole, byte for byte:
//! with voids, steps and spikes on cube edges and corners, fine insets astride a cube edge and
//! on a cube corner over coarser data, at several cut levels, with and without spilled records,
//! and resumed from a journal of finished blocks.

use std::collections::{BTreeSet, HashMap};
use std::sync::{Arc, Mutex};

use cbdam_codec::CodecError;
use cbdam_codec::entropy::CoderKind;
use cbdam_codec::geodesy::lattice_lat_lon;
use cbdam_codec::geometry::{Domain, FacePoint};
use cbdam_codec::hierarchy::planet::{
    Apex, PlanetBlocks, PlanetOutline, PlanetTiles, default_cut, encode_planet_in_blocks, thinned,
};
use cbdam_codec::hierarchy::resolution::{COARSE_ONLY, HOLE};
use cbdam_codec::hierarchy::{
    BlockJournal, BlockOutput, EncodeOptions, Encoded, NoJournal, PlanetGrid, PlanetTile,
    Resolution, encode_planet,
};
use cbdam_codec::quant::{HeightGrid, Quantizer};

use super::util::Rng;

fn noise(p: FacePoint, seed: u64) -> u64 {
    let mut r = Rng(seed ^ (u64::from(p.face) << 56) ^ ((p.x as u64) << 28) ^ p.y as u64);
    r.next()
}

fn opts(n: usize) -> EncodeOptions {
    EncodeOptions {
        n,
        coder: CoderKind::AdaptiveTokens,
        ..EncodeOptions::default()
    }
}

/// Angular distance in degrees between two latitude/longitude points.
fn degrees_apart(a: (f64, f64), b: (f64, f64)) -> f64 {
    let (la, lb) = (a.0.to_radians(), b.0.to_radians());
    let dl = (a.1 - b.1).to_radians();
    (la.sin() * lb.sin() + la.cos() * lb.cos() * dl.cos())
        .clamp(-1.0, 1.0)
        .acos()
        .to_degrees()
}

/// The points of `domain` within `radius_deg` of face `face`'s point `(x, y)`: an inset there.
fn near(domain: &Domain, p: FacePoint, face: u8, x: i64, y: i64, radius_deg: f64) -> bool {
    let ll = |f, x, y| {
        let l = lattice_lat_lon(domain, f, x, y).unwrap();
        (l.lat, l.lon)
    };
    degrees_apart(ll(p.face, p.x, p.y), ll(face, x, y)) < radius_deg
}

/// Relief with steps across cube edges, spikes on corners and (`holes`) voids, metres as units.
fn height(p: FacePoint, s: i64, seed: u64, holes: bool) -> Option<i32> {
    let on_x = p.x == 0 || p.x == s;
    let on_y = p.y == 0 || p.y == s;
    let h = noise(p, seed);
    if holes && (h.is_multiple_of(13) || (on_x && on_y && h.is_multiple_of(2))) {
        return None;
    }
    let plateau = [-9000, 4000, 12000, -300, 7000, 0][usize::from(p.face)];
    let spike = match (on_x, on_y) {
        (true, true) if h.is_multiple_of(2) => 30000,
        (true, true) => -30000,
        _ if (on_x || on_y) && (p.x == s / 2 || p.y == s / 2) => -20000,
        _ => 0,
    };
    Some(plateau + spike + (h % 2001) as i32 - 1000)
}

/// The class of a canonical point of the inset planet: stride-1 samples in two insets (one
/// astride the edge between faces 0 and its neighbour at the middle of face 0's `x = S` side,
/// one on the cube corner at face 0's `(0, 0)`), stride-4 samples elsewhere (holes where the
/// noise says), coarse only between those when the 4-step cell's corners have data.
fn inset_class(domain: &Domain, p: FacePoint, s: i64) -> u8 {
    let p = domain.canonical_point(p.face, p.x, p.y).unwrap();
    let fine = |p: FacePoint| near(domain, p, 0, s, s / 2, 12.0) || near(domain, p, 0, 0, 0, 15.0);
    let sample = |p: FacePoint| {
        let p = domain.canonical_point(p.face, p.x, p.y).unwrap();
        if fine(p) {
            0
        } else if noise(p, 11).is_multiple_of(11) {
            HOLE
        } else {
            2
        }
    };
    if fine(p) || (p.x % 4 == 0 && p.y % 4 == 0) {
        return sample(p);
    }
    let around = |v: i64| {
        let lo = v & !3;
        if lo == v { [v, v] } else { [lo, lo + 4] }
    };
    let drawn = around(p.y).iter().all(|&y| {
        around(p.x)
            .iter()
            .all(|&x| sample(FacePoint::new(p.face, x, y)) != HOLE)
    });
    if drawn { COARSE_ONLY } else { HOLE }
}

/// `whole`'s points in tiles of `2^tile_log2` steps; with `classes`, a tile holds every 4th
/// point where none of its points is a stride-1 sample.
fn retiled(
    whole: &PlanetGrid,
    tile_log2: u32,
    classes: Option<&[Resolution]>,
) -> Result<PlanetGrid, CodecError> {
    let domain = *whole.domain();
    let s = domain.cube().unwrap().side();
    let rects = PlanetGrid::tile_rects(&domain, tile_log2);
    let faces = (0..6u8)
        .map(|f| {
            rects
                .iter()
                .map(|&(x0, y0, x1, y1)| {
                    let class = classes.map(|c| &c[usize::from(f)].class);
                    let at = |x: i64, y: i64| (y * (s + 1) + x) as usize;
                    let fine = class.is_none_or(|class| {
                        (y0..=y1).any(|y| (x0..=x1).any(|x| class[at(x, y)] == 0))
                    });
                    let stride = if fine { 0 } else { 2 };
                    let step = 1usize << stride;
                    let points: Vec<(i64, i64)> = (y0..=y1)
                        .step_by(step)
                        .flat_map(|y| (x0..=x1).step_by(step).map(move |x| (x, y)))
                        .collect();
                    let grid = HeightGrid {
                        width: ((x1 - x0) >> stride) as usize + 1,
                        height: ((y1 - y0) >> stride) as usize + 1,
                        values: points
                            .iter()
                            .map(|&(x, y)| whole.get(f, x, y).unwrap_or(0))
                            .collect(),
                        valid: points
                            .iter()
                            .map(|&(x, y)| whole.get(f, x, y).is_some())
                            .collect(),
                    };
                    let held = class.map(|c| points.iter().map(|&(x, y)| c[at(x, y)]).collect());
                    PlanetTile::new(stride, (x0, y0, x1, y1), grid, held)
                })
                .collect::<Result<Vec<_>, _>>()
        })
        .collect::<Result<Vec<_>, _>>()?;
    let (n, k) = (domain.n(), domain.layout().k());
    PlanetGrid::from_tiles(n, k, tile_log2, faces, classes.is_some())
}

/// The planet with voids, steps and spikes on every cube edge and corner, in tiles of 8 steps.
fn adversarial_planet() -> PlanetGrid {
    let (n, k) = (9usize, 3u32);
    let s = ((n - 1) << k) as i64;
    let whole = PlanetGrid::from_fn(n, k, |p| height(p, s, 7, true)).unwrap();
    retiled(&whole, 3, None).unwrap()
}

/// The variable-resolution planet of [`inset_class`], in tiles of 8 steps (strided where no
/// fine data is).
fn inset_planet() -> PlanetGrid {
    let (n, k) = (9usize, 3u32);
    let domain = Domain::cube_sphere(n, k).unwrap();
    let s = ((n - 1) << k) as i64;
    let classes: Vec<Resolution> = (0..6u8)
        .map(|f| Resolution {
            class: (0..=s)
                .flat_map(|y| (0..=s).map(move |x| (x, y)))
                .map(|(x, y)| inset_class(&domain, FacePoint::new(f, x, y), s))
                .collect(),
        })
        .collect();
    let whole = PlanetGrid::from_fn(n, k, |p| {
        (inset_class(&domain, p, s) < 32).then(|| height(p, s, 9, false).unwrap())
    })
    .unwrap()
    .with_classes(classes.clone())
    .unwrap();
    retiled(&whole, 3, Some(&classes)).unwrap()
}

/// Hands out a planet's tiles, counting the tiles handed out whole at full resolution and the
/// parts of tiles (their points outside the part made holes, so that an encode reading
/// outside the strips it asked for writes other bytes).
struct Counting<'a> {
    planet: &'a PlanetGrid,
    fine_tiles: Mutex<usize>,
    parts: Mutex<usize>,
}

impl PlanetTiles for Counting<'_> {
    fn tile(&self, face: u8, index: usize, min: u32) -> Result<Arc<PlanetTile>, CodecError> {
        if min == 0 {
            *self.fine_tiles.lock().unwrap() += 1;
        }
        PlanetTiles::tile(self.planet, face, index, min)
    }

    fn tile_part(
        &self,
        face: u8,
        index: usize,
        part: (i64, i64, i64, i64),
    ) -> Result<Arc<PlanetTile>, CodecError> {
        *self.parts.lock().unwrap() += 1;
        PlanetTiles::tile_part(self.planet, face, index, part)
    }
}

/// The planet encoded in blocks of one tile, with the tiles handed out whole at full
/// resolution and the parts of tiles handed out.
fn in_blocks(planet: &PlanetGrid, cut: u8, spill: bool) -> (Encoded, usize, usize) {
    let source = Counting {
        planet,
        fine_tiles: Mutex::new(0),
        parts: Mutex::new(0),
    };
    let outline = PlanetOutline::of_planet(planet);
    let n = planet.domain().n();
    let q = Quantizer::new(3).unwrap();
    let e =
        encode_planet_in_blocks(&outline, &source, q, &opts(n), cut, &NoJournal, spill).unwrap();
    (
        e,
        source.fine_tiles.into_inner().unwrap(),
        source.parts.into_inner().unwrap(),
    )
}

fn assert_same(whole: &Encoded, blocks: &Encoded, what: &str) {
    assert_eq!(whole.params, blocks.params, "{what}: params");
    assert_eq!(whole.roots, blocks.roots, "{what}: roots");
    assert_eq!(whole.leaf_error, blocks.leaf_error, "{what}: leaf error");
    let ids = |e: &Encoded| e.records.iter().map(|r| r.id).collect::<Vec<_>>();
    let (a, b) = (ids(whole), ids(blocks));
    let extra: Vec<_> = b.iter().filter(|i| !a.contains(i)).take(5).collect();
    let missing: Vec<_> = a.iter().filter(|i| !b.contains(i)).take(5).collect();
    assert_eq!(
        a.len(),
        b.len(),
        "{what}: records; extra {extra:?} missing {missing:?}"
    );
    for (a, b) in whole.records.iter().zip(&blocks.records) {
        assert_eq!(a, b, "{what}: record {}", a.id);
    }
}

/// Voids, steps and spikes on every cube edge and corner, several cuts (the apex alone, from
/// the roots, the default, the finest level), records spilled or not: the same hierarchy.
#[test]
fn a_planet_with_voids_on_its_edges_encodes_block_by_block_as_whole() {
    let planet = adversarial_planet();
    assert!(planet.has_nodata());
    let q = Quantizer::new(3).unwrap();
    let whole = encode_planet(&planet, q, &opts(9)).unwrap();
    let finest = planet.domain().finest_level();
    let default = default_cut(planet.domain(), planet.tile_log2());
    for (cut, spill) in [(0, false), (3, true), (default, false), (finest, true)] {
        let (blocks, fine_tiles, parts) = in_blocks(&planet, cut, spill);
        assert_same(&whole, &blocks, &format!("cut {cut}"));
        // Each block reads its own tile whole and strips of a ring of neighbours, not the
        // planet.
        let tiles = 6 * PlanetGrid::tile_rects(planet.domain(), 3).len();
        assert!(fine_tiles >= tiles, "cut {cut}: {fine_tiles} tile reads");
        if cut == finest {
            // The apex reads every tile at full resolution at this cut, each block its own
            // and, of the neighbours its diamonds reach, those whose blocks come within the
            // next three (painted whole for them to find in a lattice's cache).
            assert!(
                fine_tiles <= 5 * tiles,
                "cut {cut}: {fine_tiles} of {tiles}"
            );
            assert!(parts > 0 && parts <= 9 * tiles, "cut {cut}: {parts} parts");
        }
    }
}

/// Fine insets astride a cube edge and on a cube corner over stride-4 data with holes, in
/// strided tiles: the same hierarchy block by block, at every cut.
#[test]
fn insets_on_a_cube_edge_and_corner_encode_block_by_block_as_whole() {
    let planet = inset_planet();
    let strided = (0..6u8)
        .flat_map(|f| planet.tiles(f))
        .filter(|t| t.stride > 0)
        .count();
    assert!(strided > 0, "no strided tile");
    // The insets reach past face 0 onto its neighbours (the edge) and the corner's faces.
    let fine_faces: BTreeSet<u8> = (0..6u8)
        .filter(|&f| planet.tiles(f).iter().any(|t| t.stride == 0))
        .collect();
    assert!(fine_faces.len() >= 3, "{fine_faces:?}");
    let q = Quantizer::new(3).unwrap();
    let whole = encode_planet(&planet, q, &opts(9)).unwrap();
    for cut in 0..=planet.domain().finest_level() {
        let (blocks, _, _) = in_blocks(&planet, cut, cut % 2 == 0);
        assert_same(&whole, &blocks, &format!("cut {cut}"));
    }
}

/// Per face, per tile: the stride each tile of `planet` holds its points at.
fn strides_of(planet: &PlanetGrid) -> Vec<Vec<u32>> {
    (0..6u8)
        .map(|f| planet.tiles(f).iter().map(|t| t.stride).collect())
        .collect()
}

/// Tiles grouped into blocks of a byte budget (from one tile each to whole faces): the same
/// hierarchy at every budget and cut, with fewer blocks the larger the budget.
#[test]
fn tiles_grouped_into_blocks_by_memory_encode_as_whole() {
    let planet = inset_planet();
    let outline = PlanetOutline::of_planet(&planet);
    let q = Quantizer::new(3).unwrap();
    let whole = encode_planet(&planet, q, &opts(9)).unwrap();
    let strides = strides_of(&planet);
    let tiles = 6 * PlanetGrid::tile_rects(planet.domain(), planet.tile_log2()).len();
    let default = default_cut(planet.domain(), planet.tile_log2());
    let mut counts = Vec::new();
    for budget in [0u64, 4 << 10, 64 << 10, 1 << 30] {
        for cut in [2, default] {
            let blocks =
                PlanetBlocks::new(&outline, &planet, q, &opts(9), cut, Apex::Encode(budget))
                    .unwrap()
                    .with_block_bytes(&strides, (budget, 1))
                    .unwrap();
            let count = blocks.block_count();
            let encoded = blocks.finish(&NoJournal, cut % 2 == 0).unwrap();
            assert_same(&whole, &encoded, &format!("budget {budget}, cut {cut}"));
            if cut == default {
                counts.push(count);
            }
        }
    }
    // A budget under any tile: one block per tile; the largest: one block per face.
    assert_eq!(counts[0], tiles, "{counts:?}");
    assert_eq!(*counts.last().unwrap(), 6, "{counts:?}");
    assert!(counts.windows(2).all(|w| w[0] >= w[1]), "{counts:?}");
    assert!(
        counts[1] < counts[0] && counts[2] < tiles / 16,
        "{counts:?} of {tiles} tiles"
    );
}

/// Keeps blocks in memory; after `fail_after` saves, every later save fails (a killed build).
struct MemoryJournal {
    kept: Mutex<HashMap<usize, BlockOutput>>,
    fail_after: Option<usize>,
    encoded: Mutex<usize>,
}

impl BlockJournal for MemoryJournal {
    fn load(&self, index: usize) -> Result<Option<BlockOutput>, CodecError> {
        Ok(self.kept.lock().unwrap().get(&index).cloned())
    }
    fn save(&self, index: usize, output: &BlockOutput) -> Result<(), CodecError> {
        let mut kept = self.kept.lock().unwrap();
        *self.encoded.lock().unwrap() += 1;
        if self.fail_after.is_some_and(|n| kept.len() >= n) {
            return Err(CodecError::invalid("the journal's disk is full"));
        }
        kept.insert(index, output.clone());
        Ok(())
    }
}

/// An encode stopped after some blocks, run again with the same journal, encodes only the
/// blocks not kept and gives the same hierarchy.
#[test]
fn a_block_wise_planet_encode_resumes_from_its_journal() {
    let planet = inset_planet();
    let outline = PlanetOutline::of_planet(&planet);
    let q = Quantizer::new(3).unwrap();
    let whole = encode_planet(&planet, q, &opts(9)).unwrap();
    let cut = default_cut(planet.domain(), planet.tile_log2());
    let mut journal = MemoryJournal {
        kept: Mutex::new(HashMap::new()),
        fail_after: Some(100),
        encoded: Mutex::new(0),
    };
    let e =
        encode_planet_in_blocks(&outline, &planet, q, &opts(9), cut, &journal, false).unwrap_err();
    assert!(e.to_string().contains("disk is full"), "{e}");
    assert_eq!(journal.kept.lock().unwrap().len(), 100);
    journal.fail_after = None;
    *journal.encoded.lock().unwrap() = 0;
    let resumed =
        encode_planet_in_blocks(&outline, &planet, q, &opts(9), cut, &journal, false).unwrap();
    assert_same(&whole, &resumed, "resumed");
    let blocks = 6 * PlanetGrid::tile_rects(planet.domain(), planet.tile_log2()).len();
    assert_eq!(*journal.encoded.lock().unwrap(), blocks - 100);
}

/// Tiles thinned for the apex hold the same values, validity and classes at the points they
/// keep; a tile already as coarse is handed out as it is.
#[test]
fn thinned_tiles_keep_their_points() {
    let planet = inset_planet();
    for f in 0..6u8 {
        for t in planet.tiles(f) {
            let thin = thinned(t, 3).unwrap();
            if t.stride >= 3 {
                assert!(Arc::ptr_eq(t, &thin));
                continue;
            }
            assert_eq!(thin.stride, 3);
            let (x0, y0, x1, y1) = t.rect;
            for y in (y0..=y1).step_by(8) {
                for x in (x0..=x1).step_by(8) {
                    let (a, b) = (t.index(x, y).unwrap(), thin.index(x, y).unwrap());
                    assert_eq!(t.grid.values[a], thin.grid.values[b]);
                    assert_eq!(t.grid.valid[a], thin.grid.valid[b]);
                    assert_eq!(
                        t.class.as_ref().unwrap()[a],
                        thin.class.as_ref().unwrap()[b]
                    );
                }
            }
        }
    }
}
