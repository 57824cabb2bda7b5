//! Colour builds: an 8-bit RGB image → a colour repository (paper §5), optionally laid over an
//! elevation repository's domain (`like`).

use std::path::Path;

use crate::input::{Limits, read_rgb};
use cbdam_codec::colour::{Alignment, RgbImage, encode_colour};
use cbdam_codec::geometry::Layout;
use cbdam_codec::hierarchy::{EncodeOptions, RepoKind};
use cbdam_codec::quant::QuantPlan;
use cbdam_codec::repository::GeoRef;
use cbdam_codec::repository::{Repository, write_repository};

use crate::BuildOptions;
use crate::error::{Context, Result, bail};
use crate::progress::{Progress, ProgressEvent, Stage};

/// What a colour build made.
#[derive(Clone, Debug)]
pub struct ColourSummary {
    /// Pixels per row.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Records (stored diamonds) in the repository.
    pub records: usize,
    /// The tolerance, whole 8-bit levels.
    pub max_error: u32,
    /// The YCoCg integer mapping.
    pub plan: QuantPlan,
    /// The bound this gives on each decoded R, G and B component, levels.
    pub rgb_bound: [u32; 3],
}

/// `--max-error` for colour: whole 8-bit levels, the bound on every decoded R, G and B.
pub fn colour_max_error(max_error: f64) -> Result<u32> {
    if !(max_error.is_finite()
        && max_error >= 0.0
        && max_error.fract() == 0.0
        && max_error <= 127.0)
    {
        bail!(
            "--max-error for a colour repository is a whole number of 8-bit levels, 0 … 127 \
             (the largest error of any R, G or B component), not {max_error}"
        );
    }
    Ok(max_error as u32)
}

/// `m` with `big − 1 = (small − 1) · 2^m`, if there is one.
fn power_of_two_ratio(big: u32, small: u32) -> Option<u32> {
    let (b, s) = (big.checked_sub(1)?, small.checked_sub(1)?);
    if s == 0 || b % s != 0 {
        return (b == s).then_some(0);
    }
    let r = b / s;
    r.is_power_of_two().then(|| r.trailing_zeros())
}

/// The level-pair shift `K_colour − K_elevation` that makes an image of `w × h` cover the
/// elevation's data rectangle, or a clear error.
fn shift_for(img: &RgbImage, like: &Repository, like_path: &Path) -> Result<i32> {
    let p = like.head().params();
    let (we, he) = (p.domain.data().width, p.domain.data().height);
    let (wc, hc) = (img.width as u32, img.height as u32);
    let ratio = |a: u32, b: u32| {
        power_of_two_ratio(a, b)
            .map(|m| m as i32)
            .or_else(|| power_of_two_ratio(b, a).map(|m| -(m as i32)))
    };
    match (ratio(wc, we), ratio(hc, he)) {
        (Some(a), Some(b)) if a == b => Ok(a),
        _ => bail!(
            "the colour image is {wc}×{hc} pixels but {} holds {we}×{he} samples: a colour \
             image over the same domain must be (W − 1)·2^m + 1 × (H − 1)·2^m + 1 for a whole m \
             (e.g. {we}×{he} or {}×{})",
            like_path.display(),
            2 * we - 1,
            2 * he - 1
        ),
    }
}

/// Georeferencing of an image that refines `g` by `2^shift` with the same first sample.
fn scaled_georef(g: &GeoRef, shift: i32) -> GeoRef {
    let s = 2f64.powi(-shift);
    let (px, py) = (g.pixel_x * s, g.pixel_y * s);
    let half = if g.pixel_is_area { 0.5 } else { 0.0 };
    // Keep the centre of sample (0, 0) where it was.
    let (cx, cy) = (g.origin_x + half * g.pixel_x, g.origin_y - half * g.pixel_y);
    GeoRef {
        epsg: g.epsg,
        origin_x: cx - half * px,
        origin_y: cy + half * py,
        pixel_x: px,
        pixel_y: py,
        pixel_is_area: g.pixel_is_area,
        wkt: g.wkt.clone(),
    }
}

/// The elevation repository at `path` a colour image is laid over (`--like`).
fn open_like(path: &Path) -> Result<(&Path, Repository)> {
    let r = Repository::open(path).with_context(|| format!("opening {}", path.display()))?;
    if r.head().kind() != RepoKind::Elevation {
        bail!("--like {} is not an elevation repository", path.display());
    }
    Ok((path, r))
}

/// Makes `img` encode on `like`'s lattice: its diamond size, and level pairs so that the image's
/// pixels fall on `like`'s points (`like`'s georeferencing scaled, when the image has none).
fn lay_over(
    img: &mut RgbImage,
    enc_opts: &mut EncodeOptions,
    like: &Repository,
    path: &Path,
) -> Result<()> {
    let shift = shift_for(img, like, path)?;
    let lp = like.head().params().layout();
    let k = lp.k() as i32 + shift;
    let base = Layout::covering(lp.n(), img.width, img.height, 0)?;
    if k < base.k() as i32 {
        bail!(
            "the colour image is too coarse for {}'s {} level pairs",
            path.display(),
            lp.k()
        );
    }
    enc_opts.n = lp.n();
    enc_opts.extra_level_pairs = (k - base.k() as i32) as u32;
    if img.georef.is_none() {
        img.georef = like.head().georef().map(|g| scaled_georef(g, shift));
    }
    Ok(())
}

/// Builds a colour repository from `opts.inputs` (one image), laid over `opts.like` when given
/// (whose diamond size and level pairs then replace `opts`'s).
pub fn build_colour(opts: &BuildOptions, progress: &dyn Progress) -> Result<ColourSummary> {
    let mut enc_opts = opts.encode_options();
    let max_error = colour_max_error(opts.max_error)?;
    if opts.raw_size.is_some() || opts.nodata.is_some() || opts.quantum.is_some() {
        bail!("--size, --nodata and --quantum do not apply to colour images");
    }
    crate::check_output(&opts.output)?;
    let like = opts.like.as_deref().map(open_like).transpose()?;
    let [input] = opts.inputs.as_slice() else {
        bail!(
            "a colour repository is built from one image, not {} files",
            opts.inputs.len()
        );
    };
    crate::tiles::check_regular_file(input, "input")?;
    crate::check_output_is_not_an_input(opts, &[])?;
    progress.event(ProgressEvent {
        stage: Stage::Prepare,
        done: 0,
        total: 1,
    });
    let mut img = read_rgb(input, &Limits::default())
        .with_context(|| format!("reading {}", input.display()))?;
    if let Some((path, like)) = &like {
        lay_over(&mut img, &mut enc_opts, like, path)?;
    }
    progress.event(ProgressEvent {
        stage: Stage::Prepare,
        done: 1,
        total: 1,
    });
    // As before this library existed, `threads: Some(0)` means all cores here.
    let mut pool = rayon::ThreadPoolBuilder::new();
    if let Some(t) = opts.threads {
        pool = pool.num_threads(t);
    }
    let (encoded, plan) = pool.build()?.install(|| {
        encode_colour(&img, max_error, &enc_opts, &|done, total| {
            progress.event(ProgressEvent {
                stage: Stage::Encode,
                done,
                total,
            })
        })
    })?;
    progress.event(ProgressEvent {
        stage: Stage::Write,
        done: 0,
        total: 1,
    });
    if let Some((path, like)) = &like {
        // The same check the client makes when it loads the pair: refuse now, not at view time.
        Alignment::new(
            like.head().params(),
            like.head().georef(),
            &encoded.params,
            img.georef.as_ref(),
        )
        .with_context(|| format!("laying the colour over {}", path.display()))?;
    }
    write_repository(&opts.output, &encoded, &plan, img.georef.as_ref(), None)
        .with_context(|| format!("writing {}", opts.output.display()))?;
    progress.event(ProgressEvent {
        stage: Stage::Write,
        done: 1,
        total: 1,
    });
    Ok(ColourSummary {
        width: img.width,
        height: img.height,
        records: encoded.records.len(),
        max_error,
        rgb_bound: cbdam_codec::colour::ycocg::rgb_bound(plan.quantizer.k() as u32),
        plan,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ratios_and_tolerances() {
        assert_eq!(power_of_two_ratio(65, 65), Some(0));
        assert_eq!(power_of_two_ratio(129, 65), Some(1));
        assert_eq!(power_of_two_ratio(257, 65), Some(2));
        assert_eq!(power_of_two_ratio(130, 65), None);
        assert_eq!(power_of_two_ratio(193, 65), None);
        assert_eq!(power_of_two_ratio(1, 1), Some(0));
        assert!(colour_max_error(4.0).is_ok());
        assert!(colour_max_error(0.0).is_ok());
        for bad in [-1.0, 0.5, 128.0, f64::NAN] {
            assert!(colour_max_error(bad).is_err(), "{bad}");
        }
        let g = GeoRef {
            epsg: Some(32632),
            origin_x: 100.0,
            origin_y: 200.0,
            pixel_x: 2.0,
            pixel_y: 2.0,
            pixel_is_area: true,
            wkt: None,
        };
        let s = scaled_georef(&g, 1);
        // Centre of sample (0, 0) stays at (101, 199); pixel halves.
        assert_eq!(
            (s.origin_x + 0.5 * s.pixel_x, s.origin_y - 0.5 * s.pixel_y),
            (101.0, 199.0)
        );
        assert_eq!(s.pixel_x, 1.0);
    }
}
