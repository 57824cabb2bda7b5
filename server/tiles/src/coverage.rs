//! Which quantized-mesh tiles exist at each level (`available` in `layer.json`, and the
//! children each tile's metadata lists), from the repository's coverage: the stored diamonds.
//!
//! A level-`z` tile samples repository level `L(z)` (the coarsest whose spacing suits its
//! vertices). The decoder visits level `L` only under stored diamonds of `L` and the leaves of
//! stored diamonds of `L − 1` (which lie inside their parents' boxes), so level `L` holds data
//! only inside the boxes of the stored diamonds of levels `L − 1` and `L`; elsewhere the surface
//! is a coarser level's, which the parent tile already carries. A tile is available when it
//! meets the data's bounds and one of those boxes, widened to a latitude / longitude box that
//! holds it (a superset: a tile listed but holding only coarser data is still right, one left
//! out would lose detail). Parents of available tiles are added, so availability is a tree, and
//! both root tiles always exist. On a variable-resolution planet the ocean so stops at the level
//! its records stop at, and an inset goes on to `maxzoom`.

use std::collections::{BTreeMap, HashSet};

use cbdam_codec::geometry::{DiamondId, Domain};

use crate::place::Placement;
use crate::schemes::{Scheme, TileId};

/// How much wider than a diamond's lattice half-side, in its level's own units turned to
/// degrees, the latitude / longitude box around its centre is taken: covers the rotation of a
/// UTM grid against the meridians (√2) and the cube-sphere's stretch across a face (≤ 1.3 for
/// the gnomonic map, the warp less), with room to spare.
const BOX_SLACK: f64 = 2.5;

/// The available tiles of every level `0..=max_zoom`.
#[derive(Clone, Debug)]
pub struct Availability {
    /// Per level, the available tiles `(x, y)`.
    levels: Vec<HashSet<(u32, u32)>>,
}

/// An inclusive rectangle of tiles `(x0, y0, x1, y1)` of one level.
pub type TileRange = (u32, u32, u32, u32);

impl Availability {
    /// The tiles of levels `0..=max_zoom` whose repository level holds data, from the stored
    /// diamonds `stored`; `coarsen(z)` is the level index ([`crate::surface::Surface::levels`])
    /// tiles of level `z` sample.
    pub fn of(
        domain: &Domain,
        place: &Placement,
        stored: &[DiamondId],
        max_zoom: u8,
        coarsen: impl Fn(u8) -> usize,
    ) -> Availability {
        let bounds = place.bounds();
        let finest = domain.finest_level();
        let coarsest = usize::from(finest / 2);
        let mut by_level: BTreeMap<u8, Vec<DiamondId>> = BTreeMap::new();
        for &id in stored {
            by_level.entry(id.level).or_default().push(id);
        }
        let mut levels: Vec<HashSet<(u32, u32)>> = vec![HashSet::new(); usize::from(max_zoom) + 1];
        for z in 1..=max_zoom {
            let level = finest - 2 * coarsen(z).min(coarsest) as u8;
            let set = &mut levels[usize::from(z)];
            if level <= 1 {
                // The roots and their children cover the whole domain.
                insert_range(set, z, bounds, bounds);
                continue;
            }
            for l in [level - 1, level] {
                for &id in by_level.get(&l).into_iter().flatten() {
                    let b = diamond_box(domain, place, id);
                    insert_range(set, z, b, bounds);
                }
            }
        }
        for z in (1..=usize::from(max_zoom)).rev() {
            let parents: Vec<(u32, u32)> = levels[z].iter().map(|&(x, y)| (x / 2, y / 2)).collect();
            levels[z - 1].extend(parents);
        }
        levels[0].extend([(0, 0), (1, 0)]);
        Availability { levels }
    }

    /// The tiles that meet `bbox` (west, south, east, north, degrees) and both root tiles:
    /// still a tree, since a tile's parent holds it.
    pub fn within(&self, bbox: [f64; 4]) -> Availability {
        let levels = self
            .levels
            .iter()
            .enumerate()
            .map(|(z, set)| {
                let z = z as u8;
                let keep = |&&(x, y): &&(u32, u32)| {
                    z == 0 || Scheme::Geographic.meets(TileId { z, x, y }, bbox)
                };
                set.iter().filter(keep).copied().collect()
            })
            .collect();
        Availability { levels }
    }

    /// The tiles of levels `0..=max` (all of them when `max` is deeper): still a tree.
    pub fn up_to(&self, max: u8) -> Availability {
        let levels = self.levels.iter().take(usize::from(max) + 1);
        Availability {
            levels: levels.cloned().collect(),
        }
    }

    /// The deepest level listed.
    pub fn max_zoom(&self) -> u8 {
        (self.levels.len() - 1) as u8
    }

    /// Whether tile `t` exists.
    pub fn has(&self, t: TileId) -> bool {
        self.levels
            .get(usize::from(t.z))
            .is_some_and(|s| s.contains(&(t.x, t.y)))
    }

    /// How many tiles level `z` has.
    pub fn count(&self, z: u8) -> usize {
        self.levels.get(usize::from(z)).map_or(0, HashSet::len)
    }

    /// Every available tile, level by level, in row order.
    pub fn tiles(&self) -> Vec<TileId> {
        let mut out = Vec::new();
        for (z, set) in self.levels.iter().enumerate() {
            let mut level: Vec<(u32, u32)> = set.iter().copied().collect();
            level.sort_unstable_by_key(|&(x, y)| (y, x));
            out.extend(level.into_iter().map(|(x, y)| TileId { z: z as u8, x, y }));
        }
        out
    }

    /// Level `z`'s tiles as rectangles: runs along each row, merged with the same run of the
    /// rows next to them.
    pub fn ranges(&self, z: u8) -> Vec<TileRange> {
        let Some(set) = self.levels.get(usize::from(z)) else {
            return Vec::new();
        };
        let mut tiles: Vec<(u32, u32)> = set.iter().map(|&(x, y)| (y, x)).collect();
        tiles.sort_unstable();
        // Runs (x0, x1, y).
        let mut runs: Vec<(u32, u32, u32)> = Vec::new();
        for (y, x) in tiles {
            match runs.last_mut() {
                Some(r) if r.2 == y && r.1 + 1 == x => r.1 = x,
                _ => runs.push((x, x, y)),
            }
        }
        // Rectangles still open on the previous row, keyed by (x0, x1).
        let mut open: BTreeMap<(u32, u32), TileRange> = BTreeMap::new();
        let mut done = Vec::new();
        for (x0, x1, y) in runs {
            match open.get_mut(&(x0, x1)) {
                Some(r) if r.3 + 1 == y => r.3 = y,
                _ => {
                    if let Some(r) = open.insert((x0, x1), (x0, y, x1, y)) {
                        done.push(r);
                    }
                }
            }
        }
        done.extend(open.into_values());
        done.sort_unstable_by_key(|r| (r.1, r.0));
        done
    }
}

/// Adds the tiles of level `z` meeting both `b` and the data's `bounds`.
fn insert_range(set: &mut HashSet<(u32, u32)>, z: u8, b: [f64; 4], bounds: [f64; 4]) {
    let clipped = [
        b[0].max(bounds[0]),
        b[1].max(bounds[1]),
        b[2].min(bounds[2]),
        b[3].min(bounds[3]),
    ];
    if clipped[0] >= clipped[2] || clipped[1] >= clipped[3] {
        return;
    }
    let Some((x0, y0, x1, y1)) = Scheme::Geographic.range(z, clipped) else {
        return;
    };
    for y in y0..=y1 {
        for x in x0..=x1 {
            set.insert((x, y));
        }
    }
}

/// A latitude / longitude box (west, south, east, north) holding diamond `id`'s lattice box:
/// its centre widened by [`BOX_SLACK`] half-sides; the whole band of longitudes where it
/// reaches a pole or the antimeridian.
fn diamond_box(domain: &Domain, place: &Placement, id: DiamondId) -> [f64; 4] {
    let r = domain.layout().radius(id.level) as f64;
    let (lat_deg, lon_deg) = match place {
        Placement::Planet { side } => {
            let d = BOX_SLACK * r * 90.0 / *side as f64;
            (d, d)
        }
        Placement::Geographic { georef, .. } => (
            BOX_SLACK * r * georef.pixel_y.abs(),
            BOX_SLACK * r * georef.pixel_x.abs(),
        ),
        Placement::Utm { georef, .. } => {
            let m = BOX_SLACK * r * georef.pixel_x.abs().max(georef.pixel_y.abs());
            (m / 110_574.0, m / 110_574.0)
        }
    };
    let c = place.lat_lon(id.face, f64::from(id.x), f64::from(id.y));
    let (south, north) = (c.lat - lat_deg, c.lat + lat_deg);
    if south <= -89.0 || north >= 89.0 {
        return [-180.0, south.max(-90.0), 180.0, north.min(90.0)];
    }
    let widest = south.abs().max(north.abs()).to_radians().cos();
    let dlon = lon_deg / widest;
    let (west, east) = (c.lon - dlon, c.lon + dlon);
    if west < -180.0 || east > 180.0 {
        return [-180.0, south, 180.0, north];
    }
    [west, south, east, north]
}

#[cfg(test)]
mod tests {
    use super::*;

    fn of(tiles: &[(u32, u32)]) -> Availability {
        Availability {
            levels: vec![HashSet::new(), tiles.iter().copied().collect()],
        }
    }

    /// Rows of tiles become as few rectangles as runs that line up allow; every tile is in
    /// exactly one.
    #[test]
    fn ranges_cover_each_tile_once() {
        let tiles = [(1, 0), (2, 0), (1, 1), (2, 1), (4, 1), (0, 3), (2, 3)];
        let a = of(&tiles);
        let ranges = a.ranges(1);
        assert_eq!(
            ranges,
            vec![(1, 0, 2, 1), (4, 1, 4, 1), (0, 3, 0, 3), (2, 3, 2, 3)]
        );
        let mut covered = 0;
        for (x0, y0, x1, y1) in ranges {
            covered += (x1 - x0 + 1) * (y1 - y0 + 1);
            for y in y0..=y1 {
                for x in x0..=x1 {
                    assert!(tiles.contains(&(x, y)), "({x}, {y}) is not available");
                }
            }
        }
        assert_eq!(covered as usize, tiles.len());
    }
}
