//! `cbdam synth`: a deterministic synthetic fractal terrain, raw little-endian float32.
//!
//! Diamond-square midpoint displacement on the smallest `2^k + 1` grid that holds the size,
//! cropped. Displacements come from a hash of (position, seed), so the terrain depends on
//! nothing but the arguments; their amplitude shrinks by `2^-H` per octave with roughness
//! H = 0.85, between the rolling hills and the alpine relief of the bundled SRTM tiles. Heights
//! are metres, roughly −500 … 4 500.

use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

use anyhow::{Result, bail};
use cbdam_codec::atomic::write_atomically;
use cbdam_codec::samples::{Dem, SampleType};
use clap::{Args, ValueEnum};

/// Write a synthetic fractal terrain (deterministic diamond-square) as raw little-endian
/// float32, for benchmarks.
#[derive(Args, Debug)]
pub struct SynthArgs {
    /// Side of the square grid in samples.
    #[arg(long, required_unless_present = "earth")]
    size: Option<usize>,
    /// Output raw float32 file.
    #[arg(short, long, required_unless_present = "earth")]
    output: Option<PathBuf>,
    /// Seed of the pseudo-random displacements.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Write a float32 BigTIFF (strips of 16 rows) instead of raw float32.
    #[arg(long, value_enum)]
    tiff: Option<TiffArg>,
    /// With --tiff: heights rounded to whole metres as an int16 GeoTIFF (strips of about 1 MB),
    /// georeferenced at 30 m in EPSG:32632.
    #[arg(long, requires = "tiff")]
    int16: bool,
    /// With --int16: OUTPUT is a new directory of N × N tiles of the grid sharing their edge
    /// rows and columns (as SRTM's do), `rRRRcCCC.tif`; --size must be N·t + 1.
    #[arg(long, value_name = "N", requires = "int16")]
    tiles: Option<usize>,
    /// With --tiles: every tile is the same (t+1)² terrain, mirrored across each tile edge (so
    /// neighbours agree on their shared rows and columns), generated in the memory of one tile
    /// instead of the whole grid's: for mosaics larger than memory (the 4.3 G-sample benchmark
    /// of scripts/bench-tiles.sh). The grid is then periodic, not one terrain.
    #[arg(long, requires = "tiles")]
    mirrored: bool,
    #[command(flatten)]
    earth: crate::synth_earth::EarthArgs,
}

/// Compression of `cbdam synth --tiff`.
#[derive(Clone, Copy, Debug, ValueEnum)]
pub enum TiffArg {
    /// Uncompressed.
    Plain,
    /// Deflate (fast level).
    Deflate,
}

/// A uniform value in `[-1, 1)` from a position and a seed (splitmix64 finaliser).
fn noise(x: usize, y: usize, seed: u64) -> f32 {
    let mut z = (x as u64) ^ (y as u64).rotate_left(32) ^ seed.wrapping_mul(0x9E37_79B9_7F4A_7C15);
    z = (z ^ (z >> 30)).wrapping_mul(0xBF58_476D_1CE4_E5B9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94D0_49BB_1331_11EB);
    z ^= z >> 31;
    (z >> 40) as f32 / (1u64 << 23) as f32 - 1.0
}

/// The `size × size` terrain, row-major.
pub fn terrain(size: usize, seed: u64) -> Vec<f32> {
    let side = (size.max(2) - 1).next_power_of_two() + 1;
    let mut h = vec![0f32; side * side];
    let at = |x: usize, y: usize| y * side + x;
    let s = side - 1;
    for (x, y) in [(0, 0), (s, 0), (0, s), (s, s)] {
        h[at(x, y)] = 2000.0 + 1000.0 * noise(x, y, seed);
    }
    let mut amp = 2500.0f32;
    let decay = 2f32.powf(-0.85);
    let mut step = s;
    while step > 1 {
        let half = step / 2;
        // Square step: cell centres from their four corners.
        for y in (half..side).step_by(step) {
            for x in (half..side).step_by(step) {
                let avg = (h[at(x - half, y - half)]
                    + h[at(x + half, y - half)]
                    + h[at(x - half, y + half)]
                    + h[at(x + half, y + half)])
                    / 4.0;
                h[at(x, y)] = avg + amp * noise(x, y, seed);
            }
        }
        // Diamond step: edge midpoints from their (up to four) neighbours.
        for y in (0..side).step_by(half) {
            let x0 = if (y / half).is_multiple_of(2) {
                half
            } else {
                0
            };
            for x in (x0..side).step_by(step) {
                let mut sum = 0.0;
                let mut count = 0.0;
                if x >= half {
                    sum += h[at(x - half, y)];
                    count += 1.0;
                }
                if x + half < side {
                    sum += h[at(x + half, y)];
                    count += 1.0;
                }
                if y >= half {
                    sum += h[at(x, y - half)];
                    count += 1.0;
                }
                if y + half < side {
                    sum += h[at(x, y + half)];
                    count += 1.0;
                }
                h[at(x, y)] = sum / count + amp * noise(x, y, seed);
            }
        }
        amp *= decay;
        step = half;
    }
    if side == size {
        return h;
    }
    (0..size)
        .flat_map(|y| h[y * side..y * side + size].to_vec())
        .collect()
}

/// `terrain(size, seed)` as a float32 DEM without georeferencing: the benchmark report's
/// synthetic input. Values off any lattice exercise the codec's pre-quantization path, which
/// the bundled whole-metre DEMs do not.
pub fn dem(size: usize, seed: u64) -> Dem {
    Dem {
        width: size,
        height: size,
        values: terrain(size, seed).into_iter().map(f64::from).collect(),
        sample_type: SampleType::F32,
        nodata: None,
        georef: None,
    }
}

/// Writes `terrain(size, seed)` to `path` as a float32 TIFF in strips of 16 rows, Deflate
/// compressed when `deflate`: the large GeoTIFF input of the streaming build's memory test.
pub fn write_tiff(path: &Path, size: usize, seed: u64, deflate: bool) -> Result<()> {
    use tiff::encoder::compression::DeflateLevel;
    use tiff::encoder::{Compression, TiffEncoder, colortype};
    const STRIP_ROWS: usize = 16;
    let t = terrain(size, seed);
    let side = u32::try_from(size)?;
    write_atomically::<anyhow::Error>(path, |f| {
        let w = std::io::BufWriter::with_capacity(1 << 20, f);
        let mut enc = TiffEncoder::new_big(w)?.with_compression(if deflate {
            Compression::Deflate(DeflateLevel::Fast)
        } else {
            Compression::Uncompressed
        });
        let mut img = enc.new_image::<colortype::Gray32Float>(side, side)?;
        img.rows_per_strip(STRIP_ROWS as u32)?;
        for rows in t.chunks(STRIP_ROWS * size) {
            img.write_strip(rows)?;
        }
        img.finish()?;
        Ok(())
    })
}

/// Writes `terrain(size, seed)` to `path`.
pub fn write(path: &Path, size: usize, seed: u64) -> Result<()> {
    let t = terrain(size, seed);
    write_atomically::<anyhow::Error>(path, |f| {
        let mut w = BufWriter::with_capacity(1 << 20, f);
        for v in &t {
            w.write_all(&v.to_le_bytes())?;
        }
        w.flush()?;
        Ok(())
    })
}

/// `terrain(size, seed)` rounded to whole metres as int16 GeoTIFF, georeferenced at 30 m in
/// EPSG:32632: one file at `path`, or with `tiles = Some(n)` a new directory `path` of `n × n`
/// tiles sharing their edge rows and columns (`size` = `n·t + 1`), named `rRRRcCCC.tif` so that
/// name order is row-major. The input of `scripts/bench-tiles.sh`.
pub fn write_tiff_i16(
    path: &Path,
    size: usize,
    seed: u64,
    deflate: bool,
    tiles: Option<usize>,
    mirrored: bool,
) -> Result<()> {
    use cbdam_builder::write::write_geotiff_i16;
    use cbdam_codec::repository::GeoRef;
    const SPACING: f64 = 30.0;
    let n = tiles.unwrap_or(1);
    if n == 0 || !(size - 1).is_multiple_of(n) {
        bail!("--size {size} is not N·t + 1 for --tiles {n}");
    }
    let t = (size - 1) / n;
    let to_i16 = |v: f32| v.round().clamp(-32767.0, 32767.0) as i16;
    let georef = |row: usize, col: usize| GeoRef {
        epsg: Some(32632),
        origin_x: 500_000.0 + col as f64 * SPACING,
        origin_y: 4_000_000.0 - row as f64 * SPACING,
        pixel_x: SPACING,
        pixel_y: SPACING,
        pixel_is_area: true,
        wkt: None,
    };
    let write = |file: &Path, side: (usize, usize), values: &[i16], g: &GeoRef| {
        write_atomically::<anyhow::Error>(file, |f| {
            write_geotiff_i16(f, side, values, Some(g), None, deflate)?;
            Ok(())
        })
    };
    if mirrored {
        // One tile's terrain; tile (tr, tc) reads it flipped left–right when tc is odd and
        // top–bottom when tr is odd, so that a shared edge is the same row or column of it.
        std::fs::create_dir(path)?;
        let base: Vec<i16> = terrain(t + 1, seed).into_iter().map(to_i16).collect();
        let side = t + 1;
        let mut tile = vec![0i16; side * side];
        for tr in 0..n {
            for tc in 0..n {
                for r in 0..side {
                    let br = if tr % 2 == 1 { t - r } else { r };
                    for c in 0..side {
                        let bc = if tc % 2 == 1 { t - c } else { c };
                        tile[r * side + c] = base[br * side + bc];
                    }
                }
                let file = path.join(format!("r{tr:03}c{tc:03}.tif"));
                write(&file, (side, side), &tile, &georef(tr * t, tc * t))?;
            }
        }
        return Ok(());
    }
    let heights: Vec<i16> = terrain(size, seed).into_iter().map(to_i16).collect();
    let Some(n) = tiles else {
        return write(path, (size, size), &heights, &georef(0, 0));
    };
    std::fs::create_dir(path)?;
    let mut tile = Vec::with_capacity((t + 1) * (t + 1));
    for tr in 0..n {
        for tc in 0..n {
            tile.clear();
            for r in tr * t..=tr * t + t {
                tile.extend_from_slice(&heights[r * size + tc * t..=r * size + tc * t + t]);
            }
            let file = path.join(format!("r{tr:03}c{tc:03}.tif"));
            write(&file, (t + 1, t + 1), &tile, &georef(tr * t, tc * t))?;
        }
    }
    Ok(())
}

pub fn run(args: &SynthArgs) -> Result<()> {
    if let Some(dir) = &args.earth.earth {
        if args.size.is_some() || args.output.is_some() || args.tiff.is_some() {
            bail!("--earth writes its own tiles: --size, -o and --tiff do not apply");
        }
        return crate::synth_earth::run(dir, &args.earth);
    }
    let (Some(size), Some(output)) = (args.size, args.output.clone()) else {
        bail!("--size and -o are needed (or --earth DIR)");
    };
    if size < 2 {
        bail!("--size must be at least 2");
    }
    if args.int16 {
        let deflate = matches!(args.tiff, Some(TiffArg::Deflate));
        return write_tiff_i16(&output, size, args.seed, deflate, args.tiles, args.mirrored);
    }
    match args.tiff {
        None => write(&output, size, args.seed),
        Some(TiffArg::Plain) => write_tiff(&output, size, args.seed, false),
        Some(TiffArg::Deflate) => write_tiff(&output, size, args.seed, true),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn terrain_is_deterministic_finite_and_varied() {
        let a = terrain(33, 7);
        assert_eq!(a, terrain(33, 7));
        assert_ne!(a, terrain(33, 8));
        assert!(
            a.iter()
                .all(|v| v.is_finite() && (-3000.0..8000.0).contains(v))
        );
        let (lo, hi) = a
            .iter()
            .fold((f32::MAX, f32::MIN), |(l, h), &v| (l.min(v), h.max(v)));
        assert!(hi - lo > 100.0, "relief {lo}…{hi}");
        // A crop of a non-power-of-two size is the top-left corner of the full grid.
        let b = terrain(20, 7);
        assert_eq!(b.len(), 400);
        assert_eq!(&b[20..40], &a[33..53]);
    }
}
