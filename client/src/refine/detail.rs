//! Procedural detail synthesis past the finest stored level (paper Fig. 6).
//!
//! Refining a diamond with no record predicts its cell values from its grid (the codec's own
//! cell predictor, α = 1 so vertices stay put and the cut stays conforming) and adds a
//! zero-centred uniform residual. The residual is a hash of the seed and the cell's lattice
//! position, so it is deterministic and independent of the order diamonds are refined in, and
//! its magnitude is at most `amplitude × (grid spacing of the new level)`, so it is bounded and
//! shrinks level by level like terrain detail does.

use cbdam_codec::geometry::{DiamondId, Layout};
use cbdam_codec::hierarchy::Refined;
use cbdam_codec::lifting::{MAX_ABS_HEIGHT, clamp_prediction, predict_cells};

use crate::world::World;

/// Settings of detail synthesis.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DetailConfig {
    /// Level pairs synthesised below the finest stored level (each pair halves the spacing).
    pub level_pairs: u32,
    /// Largest residual as a fraction of the new level's grid spacing (the paper uses 0.3 of
    /// the triangle edge length; smaller keeps synthetic slopes tame).
    pub amplitude: f64,
    /// Seed of the residuals.
    pub seed: u64,
}

impl Default for DetailConfig {
    fn default() -> Self {
        Self {
            level_pairs: 1,
            amplitude: 0.1,
            seed: 0x5eed_c0de,
        }
    }
}

/// Grid spacing in metres of the diamonds of `level`.
fn spacing_metres(world: &World, level: u8) -> f64 {
    let layout = world.domain.layout();
    let r = layout.radius(level) as f64;
    let n1 = (layout.n() - 1) as f64;
    let lattice = if level.is_multiple_of(2) {
        2.0 * r / n1
    } else {
        r / n1 * std::f64::consts::SQRT_2
    };
    lattice * world.mean_step()
}

/// Largest residual, in height units, that refining a diamond of `level` adds (its cells are
/// the vertices of level `level + 1`).
pub(crate) fn amplitude_units(world: &World, config: &DetailConfig, level: u8) -> i32 {
    let metres = config.amplitude * spacing_metres(world, level + 1);
    (metres / world.unit).floor().clamp(0.0, 1e6) as i32
}

fn mix(mut z: u64) -> u64 {
    z = z.wrapping_add(0x9e37_79b9_7f4a_7c15);
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// The residual at doubled lattice position `(x2, y2)`, uniform in `-amp..=amp`.
pub(crate) fn residual(seed: u64, x2: i64, y2: i64, amp: i32) -> i32 {
    if amp <= 0 {
        return 0;
    }
    let h = mix(seed ^ mix((x2 as u64) << 32 ^ (y2 as u64 & 0xffff_ffff)));
    (h % (2 * amp as u64 + 1)) as i32 - amp
}

/// Refines diamond `id` with grid `p` procedurally. `valid` is the grid's validity (`None`: all
/// valid); a new point is valid only where all four vertices around it are, so detail never
/// spreads into a nodata hole.
pub(crate) fn synthesize(
    layout: &Layout,
    id: DiamondId,
    p: &[i32],
    valid: Option<&[bool]>,
    amp: i32,
    seed: u64,
) -> Refined {
    let n = layout.n();
    let m = n - 1;
    let mut cells = vec![0i32; m * m];
    predict_cells(p, n, &mut cells);
    let g = layout.grid(id);
    for j in 0..m {
        for i in 0..m {
            let (x2, y2) = g.point2(2 * i as i64 + 1, 2 * j as i64 + 1);
            let c = &mut cells[j * m + i];
            let v = clamp_prediction(i64::from(*c)) + i64::from(residual(seed, x2, y2, amp));
            *c = v.clamp(-i64::from(MAX_ABS_HEIGHT), i64::from(MAX_ABS_HEIGHT)) as i32;
        }
    }
    let half_step = valid.map(|v| {
        let side = 2 * n - 1;
        let mut out = vec![false; side * side];
        for j in 0..n {
            for i in 0..n {
                out[2 * j * side + 2 * i] = v[j * n + i];
            }
        }
        for j in 0..m {
            for i in 0..m {
                out[(2 * j + 1) * side + 2 * i + 1] = v[j * n + i]
                    && v[j * n + i + 1]
                    && v[(j + 1) * n + i]
                    && v[(j + 1) * n + i + 1];
            }
        }
        out
    });
    Refined::from_parts(n, p, &cells).with_validity(half_step)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn residuals_are_bounded_deterministic_and_not_constant() {
        let mut seen = std::collections::HashSet::new();
        for x in 0..200 {
            for y in 0..50 {
                let r = residual(42, x, y, 7);
                assert!((-7..=7).contains(&r));
                assert_eq!(r, residual(42, x, y, 7));
                seen.insert(r);
            }
        }
        assert_eq!(seen.len(), 15, "every value in range occurs");
        assert_eq!(residual(42, 3, 4, 0), 0);
        assert_ne!(
            (0..64).map(|x| residual(1, x, 0, 100)).collect::<Vec<_>>(),
            (0..64).map(|x| residual(2, x, 0, 100)).collect::<Vec<_>>()
        );
    }

    #[test]
    fn synthesis_adds_bounded_residuals_to_the_prediction() {
        let layout = Layout::new(9, 2, 1, 1).unwrap();
        let id = layout.roots().next().unwrap();
        let n = layout.n();
        let p: Vec<i32> = (0..n * n).map(|i| (i as i32 * 37) % 101).collect();
        let r = synthesize(&layout, id, &p, None, 5, 9);
        let mut pred = vec![0; (n - 1) * (n - 1)];
        predict_cells(&p, n, &mut pred);
        let mut differs = false;
        for j in 0..n - 1 {
            for i in 0..n - 1 {
                let d = r.cell(i, j) - pred[j * (n - 1) + i];
                assert!(d.abs() <= 5);
                differs |= d != 0;
            }
        }
        assert!(differs);
        for j in 0..n {
            for i in 0..n {
                assert_eq!(r.vertex(i, j), p[j * n + i], "vertices stay put");
            }
        }
        assert_eq!(r, synthesize(&layout, id, &p, None, 5, 9));
    }
}
