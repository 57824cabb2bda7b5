//! Bits per sample of the adaptive coder against the paper's quadtree + Elias-gamma cost on
//! residuals of a simple closed-loop interpolation pyramid over the sample DEMs.
//!
//! `cargo run --release -p cbdam-codec --example residual_rate`

use cbdam_codec::entropy::{Band, BandKind, CoderKind, encode_bands};
use std::fs::File;
use tiff::decoder::{Decoder, DecodingResult};

const BAND: usize = 64;

fn read_tiff(path: &str) -> (usize, usize, Vec<f64>) {
    let mut d = Decoder::new(File::open(path).expect(path)).expect("tiff");
    let (w, h) = d.dimensions().expect("dimensions");
    let v: Vec<f64> = match d.read_image().expect("image") {
        DecodingResult::I16(v) => v.into_iter().map(f64::from).collect(),
        DecodingResult::F32(v) => v.into_iter().map(f64::from).collect(),
        _ => panic!("{path}: unexpected sample type"),
    };
    (w as usize, h as usize, v)
}

/// Quadtree + Elias-gamma bits of a band (see the adaptive coder's tests for the rule).
fn gamma_bits(v: &[i32], stride: usize, x0: usize, y0: usize, w: usize, h: usize) -> u64 {
    let nonzero = (y0..y0 + h).any(|y| v[y * stride + x0..][..w].iter().any(|&a| a != 0));
    if !nonzero {
        return 1;
    }
    if w == 1 && h == 1 {
        return 3 + 2 * u64::from(v[y0 * stride + x0].unsigned_abs().ilog2());
    }
    let (w1, h1) = (w.div_ceil(2), h.div_ceil(2));
    let kids = [
        (x0, y0, w1, h1),
        (x0 + w1, y0, w - w1, h1),
        (x0, y0 + h1, w1, h - h1),
        (x0 + w1, y0 + h1, w - w1, h - h1),
    ];
    1 + kids
        .iter()
        .filter(|k| k.2 > 0 && k.3 > 0)
        .map(|&(x, y, cw, ch)| gamma_bits(v, stride, x, y, cw, ch))
        .sum::<u64>()
}

#[derive(Default)]
struct Tally {
    samples: u64,
    adaptive_bits: u64,
    gamma_bits: u64,
}

impl Tally {
    /// Cuts a residual grid into 64×64 records and codes each on its own.
    fn add(&mut self, grid: &[i32], w: usize, h: usize) {
        for by in (0..h).step_by(BAND) {
            for bx in (0..w).step_by(BAND) {
                let (bw, bh) = ((w - bx).min(BAND), (h - by).min(BAND));
                let v: Vec<i32> = (0..bh)
                    .flat_map(|y| grid[(by + y) * w + bx..][..bw].to_vec())
                    .collect();
                let mut out = Vec::new();
                let band = Band {
                    kind: BandKind::Cells,
                    width: bw,
                    height: bh,
                    values: &v,
                };
                encode_bands(CoderKind::Adaptive, &[band], &mut out);
                self.samples += (bw * bh) as u64;
                self.adaptive_bits += out.len() as u64 * 8;
                self.gamma_bits += gamma_bits(&v, bw, 0, 0, bw, bh).div_ceil(8) * 8;
            }
        }
    }
}

/// Codes one `(2^n + 1)²` window of integer heights with a dyadic closed-loop pyramid: at each
/// step, square centres from their 4 corners, then edge midpoints from their 2–4 diamond
/// neighbours; residuals are quantized with step 2k+1 and the reconstruction feeds later
/// predictions.
fn pyramid(z: &[i64], n: usize, k: i64, tally: &mut Tally) {
    let side = n + 1;
    let mut rec = vec![i64::MIN; side * side];
    let coarse = 64.min(n);
    for y in (0..side).step_by(coarse) {
        for x in (0..side).step_by(coarse) {
            rec[y * side + x] = z[y * side + x];
        }
    }
    let q = 2 * k + 1;
    let code = |rec: &mut Vec<i64>,
                pts: &[(usize, usize)],
                nb: &dyn Fn(usize, usize) -> Vec<(usize, usize)>| {
        pts.iter()
            .map(|&(x, y)| {
                let ns = nb(x, y);
                let sum: i64 = ns.iter().map(|&(a, b)| rec[b * side + a]).sum();
                let pred = (2 * sum + ns.len() as i64).div_euclid(2 * ns.len() as i64);
                let idx = (z[y * side + x] - pred + k).div_euclid(q);
                rec[y * side + x] = pred + idx * q;
                idx as i32
            })
            .collect::<Vec<i32>>()
    };
    let mut s = coarse;
    while s >= 2 {
        let m = n / s;
        let h = s / 2;
        let centres: Vec<_> = (0..m)
            .flat_map(|j| (0..m).map(move |i| (i * s + h, j * s + h)))
            .collect();
        let r = code(&mut rec, &centres, &|x, y| {
            vec![
                (x - h, y - h),
                (x + h, y - h),
                (x - h, y + h),
                (x + h, y + h),
            ]
        });
        tally.add(&r, m, m);
        let diamond = |x: usize, y: usize| {
            let mut v = Vec::with_capacity(4);
            if x >= h {
                v.push((x - h, y));
            }
            if x + h <= n {
                v.push((x + h, y));
            }
            if y >= h {
                v.push((x, y - h));
            }
            if y + h <= n {
                v.push((x, y + h));
            }
            v
        };
        let horiz: Vec<_> = (0..=m)
            .flat_map(|j| (0..m).map(move |i| (i * s + h, j * s)))
            .collect();
        let r = code(&mut rec, &horiz, &diamond);
        tally.add(&r, m, m + 1);
        let vert: Vec<_> = (0..m)
            .flat_map(|j| (0..=m).map(move |i| (i * s, j * s + h)))
            .collect();
        let r = code(&mut rec, &vert, &diamond);
        tally.add(&r, m + 1, m);
        s = h;
    }
    debug_assert!(rec.iter().zip(z).all(|(r, z)| (r - z).abs() <= k));
}

fn main() {
    let data = [
        ("data/srtm3_demcompare.tif", 512usize, None),
        ("data/lidar1m_mn.tif", 256, Some(8.0)),
    ];
    for (path, n, unit_div) in data {
        let path = format!("{}/../{path}", env!("CARGO_MANIFEST_DIR"));
        let (w, h, heights) = read_tiff(&path);
        for eps in [0.5f64, 1.0, 2.0, 5.0] {
            // SRTM heights are whole metres; the lidar heights go on a lattice of ε/8.
            let u = unit_div.map_or(1.0, |d| eps / d);
            let k = (eps / u).floor() as i64;
            let mut tally = Tally::default();
            // Four corner windows cover most of the raster.
            for (ox, oy) in [
                (0, 0),
                (w - n - 1, 0),
                (0, h - n - 1),
                (w - n - 1, h - n - 1),
            ] {
                let z: Vec<i64> = (0..=n)
                    .flat_map(|y| (0..=n).map(move |x| (oy + y) * w + ox + x))
                    .map(|i| (heights[i] / u).round() as i64)
                    .collect();
                pyramid(&z, n, k, &mut tally);
            }
            let name = path.rsplit('/').next().unwrap_or(&path);
            println!(
                "{name:24} eps {eps:>3} m  k {k:>2}  adaptive {:.3}  gamma {:.3}  bits/sample  ({} samples)",
                tally.adaptive_bits as f64 / tally.samples as f64,
                tally.gamma_bits as f64 / tally.samples as f64,
                tally.samples
            );
        }
    }
}
