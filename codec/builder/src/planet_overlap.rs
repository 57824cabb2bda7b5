//! A planet's inputs of one spacing that overlap — SRTM's shared edge rows and columns (1201²
//! tiles of 1° repeat their neighbours' border), two tiles for one cell — must hold the same
//! valid samples there, as a plane's tiles must (`docs/BUILD.md`); nodata on one side is fine.
//!
//! Checked as each input is read once for the height range ([`crate::planet_input`]'s
//! `PlanetInputs::range`), with no pass of its own: when an input is read, the border samples
//! of the inputs read before it that lie on its samples are compared with them. Only the
//! borders (four lines of samples) of inputs some of whose overlapping partners are still
//! unread are kept, so memory follows the tiles "in flight" (about one row of tiles for tiles
//! given in name order), not the number of inputs. Inputs overlap when they share a sample
//! grid: the same frame (latitude/longitude, or one UTM zone), the same spacing and sample
//! positions a whole number of samples apart (across the antimeridian too). Inputs around the
//! globe (which wrap) and inputs of other spacings are not compared: among those the finest
//! wins, as `docs/PLANET.md` says.

use std::collections::HashMap;

use crate::band_cache::Samples;
use crate::error::{Result, bail};
use crate::planet_input::{Frame, PlanetInput};

/// Where an input's samples lie on the sample grid it shares with others.
#[derive(Clone, Copy)]
struct Placement {
    /// Index of the grid among the inputs' grids.
    grid: usize,
    /// Global column and row of sample (0, 0): columns east, rows south.
    col0: i64,
    row0: i64,
    /// Columns per 360° of a geographic grid whose spacing divides it, for the antimeridian.
    period: Option<i64>,
}

/// An input's border samples (NaN where not valid): rows 0 and `h − 1`, columns 0 and `w − 1`.
struct Border {
    top: Vec<f64>,
    bottom: Vec<f64>,
    left: Vec<f64>,
    right: Vec<f64>,
}

/// The check's state over one pass of reads; see the module notes.
pub(crate) struct SharedEdges {
    placements: Vec<Option<Placement>>,
    /// The inputs overlapping each input.
    partners: Vec<Vec<usize>>,
    /// Partners of each input not yet read.
    unread: Vec<usize>,
    read: Vec<bool>,
    borders: HashMap<usize, Border>,
}

/// The grid an input's samples lie on — a key equal for inputs that share one — and its
/// placement there; `None` for an input around the globe.
fn grid_of(input: &PlanetInput) -> Option<(String, i64, i64, Option<i64>)> {
    let (kind, x0, y0, dx, dy, period) = match input.frame {
        Frame::Geographic {
            period: Some(_), ..
        } => return None,
        Frame::Geographic {
            lon0,
            lat0,
            dlon,
            dlat,
            ..
        } => {
            let turn = 360.0 / dlon;
            let period = ((turn - turn.round()).abs() < 1e-6).then_some(turn.round() as i64);
            ("geographic".to_string(), lon0, -lat0, dlon, dlat, period)
        }
        Frame::Projected {
            utm,
            x0,
            y0,
            dx,
            dy,
        } => (format!("{utm:?}"), x0, -y0, dx, dy, None),
    };
    let (cx, cy) = (x0 / dx, y0 / dy);
    // Spacings and the fraction of a sample the grid is offset by, to a millionth.
    let micro = |v: f64| (v * 1e6).round() as i64;
    let key = format!(
        "{kind} {} {} {} {}",
        (dx * 1e12).round() as i64,
        (dy * 1e12).round() as i64,
        micro(cx - cx.round()),
        micro(cy - cy.round())
    );
    let col0 = match period {
        Some(p) => (cx.round() as i64).rem_euclid(p),
        None => cx.round() as i64,
    };
    Some((key, col0, cy.round() as i64, period))
}

/// Column shifts (whole turns) under which `a` and `b` may overlap.
fn shifts(a: &Placement) -> impl Iterator<Item = i64> {
    let p = a.period.unwrap_or(0);
    [0, -p, p].into_iter().take(if p == 0 { 1 } else { 3 })
}

impl SharedEdges {
    /// The check over `inputs`, none read yet: which inputs overlap which.
    pub(crate) fn new(inputs: &[PlanetInput]) -> Self {
        let mut keys: HashMap<String, usize> = HashMap::new();
        let placements: Vec<Option<Placement>> = inputs
            .iter()
            .map(|i| {
                let (key, col0, row0, period) = grid_of(i)?;
                let n = keys.len();
                let grid = *keys.entry(key).or_insert(n);
                Some(Placement {
                    grid,
                    col0,
                    row0,
                    period,
                })
            })
            .collect();
        let partners = partners_of(inputs, &placements);
        let unread = partners.iter().map(Vec::len).collect();
        Self {
            placements,
            partners,
            unread,
            read: vec![false; inputs.len()],
            borders: HashMap::new(),
        }
    }

    /// Borders kept now (for tests of the memory bound).
    #[cfg(test)]
    pub(crate) fn kept(&self) -> usize {
        self.borders.len()
    }

    /// Input `j` was read (`samples`): compares it with the borders of the overlapping inputs
    /// read before it, refusing a disagreement by both names, and keeps its own border while
    /// an input overlapping it is still unread.
    pub(crate) fn check(
        &mut self,
        inputs: &[PlanetInput],
        j: usize,
        samples: &Samples,
    ) -> Result<()> {
        let Some(pj) = self.placements[j] else {
            return Ok(());
        };
        for &i in &self.partners[j] {
            if self.read[i] {
                let border = &self.borders[&i];
                let pi = self.placements[i].expect("a partner has a placement");
                compare(inputs, (i, &pi, border), (j, &pj, samples))?;
            }
        }
        self.read[j] = true;
        for k in 0..self.partners[j].len() {
            let i = self.partners[j][k];
            self.unread[i] -= 1;
            if self.read[i] && self.unread[i] == 0 {
                self.borders.remove(&i);
            }
        }
        if self.unread[j] > 0 {
            self.borders.insert(j, border_of(&inputs[j], samples));
        }
        Ok(())
    }
}

/// The inputs overlapping each input: those on the same grid whose sample rectangles meet,
/// found through buckets as wide as the grid's largest input (so a partner is in its own
/// bucket or a neighbouring one).
fn partners_of(inputs: &[PlanetInput], placements: &[Option<Placement>]) -> Vec<Vec<usize>> {
    let mut side: HashMap<usize, i64> = HashMap::new();
    for (input, p) in inputs.iter().zip(placements) {
        if let Some(p) = p {
            let s = side.entry(p.grid).or_insert(1);
            *s = (*s).max(input.width.max(input.height) as i64);
        }
    }
    let bucket_of = |p: &Placement, dx: i64, dy: i64| {
        let s = side[&p.grid];
        let mut bx = p.col0.div_euclid(s) + dx;
        if let Some(period) = p.period {
            bx = bx.rem_euclid((period + s - 1) / s);
        }
        (p.grid, bx, p.row0.div_euclid(s) + dy)
    };
    let mut buckets: HashMap<(usize, i64, i64), Vec<usize>> = HashMap::new();
    for (k, p) in placements.iter().enumerate() {
        if let Some(p) = p {
            buckets.entry(bucket_of(p, 0, 0)).or_default().push(k);
        }
    }
    let mut partners = vec![Vec::new(); inputs.len()];
    for (a, pa) in placements.iter().enumerate() {
        let Some(pa) = pa else { continue };
        let mut found: Vec<usize> = (-1..=1)
            .flat_map(|dx| (-1..=1).map(move |dy| (dx, dy)))
            .filter_map(|(dx, dy)| buckets.get(&bucket_of(pa, dx, dy)))
            .flatten()
            .copied()
            .filter(|&b| b != a)
            .filter(|&b| {
                let pb = placements[b].as_ref().expect("bucketed");
                overlap(pa, &inputs[a], pb, &inputs[b]).is_some()
            })
            .collect();
        found.sort_unstable();
        found.dedup();
        partners[a] = found;
    }
    partners
}

/// The column shift under which `b`'s samples meet `a`'s, if they do.
fn overlap(pa: &Placement, a: &PlanetInput, pb: &Placement, b: &PlanetInput) -> Option<i64> {
    let rows = pa.row0 < pb.row0 + b.height as i64 && pb.row0 < pa.row0 + a.height as i64;
    if !rows {
        return None;
    }
    shifts(pa).find(|shift| {
        let b0 = pb.col0 + shift;
        pa.col0 < b0 + b.width as i64 && b0 < pa.col0 + a.width as i64
    })
}

/// The border samples of `input` (NaN where not valid).
fn border_of(input: &PlanetInput, samples: &Samples) -> Border {
    let (w, h) = (input.width, input.height);
    let at = |c, r| input.sample(samples, c, r).unwrap_or(f64::NAN);
    Border {
        top: (0..w).map(|c| at(c, 0)).collect(),
        bottom: (0..w).map(|c| at(c, h - 1)).collect(),
        left: (0..h).map(|r| at(0, r)).collect(),
        right: (0..h).map(|r| at(w - 1, r)).collect(),
    }
}

/// The positions `(c, r)` of a `w` × `h` input's border, each once.
fn border_positions(w: usize, h: usize) -> impl Iterator<Item = (usize, usize)> {
    let rows = (0..w).flat_map(move |c| [(c, 0), (c, h - 1)]);
    let columns = (1..h - 1).flat_map(move |r| [(0, r), (w - 1, r)]);
    rows.chain(columns)
}

impl Border {
    fn at(&self, (w, h): (usize, usize), (c, r): (usize, usize)) -> f64 {
        match (c, r) {
            (c, 0) => self.top[c],
            (c, r) if r == h - 1 => self.bottom[c],
            (0, r) => self.left[r],
            (c, r) if c == w - 1 => self.right[r],
            _ => f64::NAN,
        }
    }
}

/// Compares the border of input `i` (read before) with input `j`'s samples where they meet.
fn compare(
    inputs: &[PlanetInput],
    (i, pi, border): (usize, &Placement, &Border),
    (j, pj, samples): (usize, &Placement, &Samples),
) -> Result<()> {
    let (a, b) = (&inputs[i], &inputs[j]);
    let Some(shift) = overlap(pj, b, pi, a) else {
        return Ok(());
    };
    // `a`'s column `c` is `b`'s column `c + dc`, row `r` its row `r + dr`.
    let dc = pi.col0 + shift - pj.col0;
    let dr = pi.row0 - pj.row0;
    let (mut shared, mut bad, mut most) = (0u64, 0u64, 0f64);
    let mut first = None;
    for (c, r) in border_positions(a.width, a.height) {
        let (cb, rb) = (c as i64 + dc, r as i64 + dr);
        if !(0..b.width as i64).contains(&cb) || !(0..b.height as i64).contains(&rb) {
            continue;
        }
        let va = border.at((a.width, a.height), (c, r));
        let Some(vb) = b.sample(samples, cb as usize, rb as usize) else {
            continue;
        };
        if va.is_nan() {
            continue;
        }
        shared += 1;
        if va != vb {
            bad += 1;
            most = most.max((va - vb).abs());
            first.get_or_insert((c, r, va, vb));
        }
    }
    if let Some((c, r, va, vb)) = first {
        let ll = a.lat_lon_of(c, r);
        bail!(
            "tiles {} and {} disagree on {bad} of their {shared} shared samples by up to {most} \
             m, first at latitude {:.6}°, longitude {:.6}° ({va} against {vb}): inputs of the \
             same spacing must hold the same values where they overlap (SRTM's shared edge rows \
             and columns)",
            a.path.display(),
            b.path.display(),
            ll.lat,
            ll.lon
        );
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::planet_input::SampleSource;
    use std::path::PathBuf;
    use std::sync::Arc;

    /// Samples per side of a test tile of 1°: 4 steps of 0.25°, the border shared as SRTM's.
    const SIDE: usize = 5;

    /// A smooth height at a global grid position, the same whichever tile holds it.
    fn height(col: i64, row: i64) -> f64 {
        (col * 7 + row * 3).rem_euclid(1000) as f64
    }

    /// The 1° tile whose south-west corner is at (`lat`, `lon`), holding `height`.
    fn tile(lat: i64, lon: i64) -> (PlanetInput, Samples) {
        let d = 1.0 / (SIDE - 1) as f64;
        let (col0, row0) = (lon * 4, -(lat + 1) * 4);
        let values: Vec<f64> = (0..SIDE * SIDE)
            .map(|k| height(col0 + (k % SIDE) as i64, row0 + (k / SIDE) as i64))
            .collect();
        let samples = Samples::compact(values.clone());
        let input = PlanetInput {
            path: PathBuf::from(format!("N{lat}E{lon}.hgt")),
            width: SIDE,
            height: SIDE,
            source: SampleSource::Held(Arc::new(Samples::compact(values))),
            nodata: None,
            frame: Frame::Geographic {
                lon0: lon as f64,
                lat0: (lat + 1) as f64,
                dlon: d,
                dlat: d,
                period: None,
            },
            spacing_deg: d,
        };
        (input, samples)
    }

    /// Reads `tiles` in order through the check; the first refusal.
    fn read_all(tiles: Vec<(PlanetInput, Samples)>) -> (Result<()>, usize) {
        let (inputs, samples): (Vec<_>, Vec<_>) = tiles.into_iter().unzip();
        let mut edges = SharedEdges::new(&inputs);
        let mut most_kept = 0;
        for (j, s) in samples.iter().enumerate() {
            if let Err(e) = edges.check(&inputs, j, s) {
                return (Err(e), most_kept);
            }
            most_kept = most_kept.max(edges.kept());
        }
        assert_eq!(edges.kept(), 0, "borders kept after every tile was read");
        (Ok(()), most_kept)
    }

    fn changed(mut t: (PlanetInput, Samples), (c, r): (usize, usize)) -> (PlanetInput, Samples) {
        let mut v: Vec<f64> = (0..SIDE * SIDE).map(|k| t.1.get(k)).collect();
        v[r * SIDE + c] += 2.0;
        t.1 = Samples::compact(v);
        t
    }

    /// Tiles whose shared edges agree pass, and only the borders of tiles with an unread
    /// neighbour are kept: for 4 rows of 6 tiles in name order, at most a row and one more.
    #[test]
    fn agreeing_tiles_pass_keeping_about_a_row_of_borders() {
        let tiles = (0..4)
            .flat_map(|lat| (0..6).map(move |lon| tile(lat, lon)))
            .collect();
        let (r, most_kept) = read_all(tiles);
        r.unwrap();
        assert!((6..=7).contains(&most_kept), "{most_kept} borders kept");
    }

    /// A shared column, a shared row, a shared corner and a duplicate tile that disagree are
    /// each refused, naming both tiles and the first sample.
    #[test]
    fn disagreeing_tiles_are_refused_by_name() {
        // The east column of N0E0 is the west column of N0E1 (row 2: latitude 0.5°).
        let e = read_all(vec![tile(0, 0), changed(tile(0, 1), (0, 2))])
            .0
            .unwrap_err();
        let e = e.to_string();
        assert!(
            e.contains(
                "N0E0.hgt and N0E1.hgt disagree on 1 of their 5 shared samples by up to 2 m"
            ) && e.contains("latitude 0.500000°, longitude 1.000000°"),
            "{e}"
        );
        // The north row of N0E0 is the south row of N1E0.
        let e = read_all(vec![changed(tile(0, 0), (3, 0)), tile(1, 0)])
            .0
            .unwrap_err();
        assert!(e.to_string().contains("N0E0.hgt and N1E0.hgt"), "{e}");
        // N0E0's north-east corner is N1E1's south-west one.
        let e = read_all(vec![tile(0, 0), changed(tile(1, 1), (0, 4))])
            .0
            .unwrap_err();
        assert!(e.to_string().contains("of their 1 shared samples"), "{e}");
        // Two tiles for one cell: compared on the border of the one read first.
        let e = read_all(vec![tile(0, 0), changed(tile(0, 0), (4, 4))])
            .0
            .unwrap_err();
        assert!(e.to_string().contains("of their 16 shared samples"), "{e}");
        // A change inside a tile touches no shared sample.
        read_all(vec![tile(0, 0), changed(tile(0, 1), (2, 2))])
            .0
            .unwrap();
    }

    /// Tiles either side of the antimeridian share its column; a nodata sample on one side
    /// is no disagreement.
    #[test]
    fn the_antimeridian_and_nodata() {
        let east = tile(0, 179);
        // W180's columns are E180's: the same heights, a turn (1440 columns) west.
        let mut west = tile(0, -180);
        let v: Vec<f64> = (0..SIDE * SIDE)
            .map(|k| height(180 * 4 + (k % SIDE) as i64, -4 + (k / SIDE) as i64))
            .collect();
        west.1 = Samples::compact(v);
        read_all(vec![east, west]).0.unwrap();
        let e = read_all(vec![tile(0, 179), changed(tile(0, -180), (0, 1))])
            .0
            .unwrap_err();
        assert!(e.to_string().contains("N0E179.hgt and N0E-180.hgt"), "{e}");
        let mut void = changed(tile(0, 1), (0, 2));
        void.0.nodata = Some(void.1.get(2 * SIDE));
        read_all(vec![tile(0, 0), void]).0.unwrap();
    }
}
