//! `cbdam verify`: every checksum, every level, every sample. The comparisons are
//! [`cbdam_builder::verify`]'s; this prints them.

use std::path::PathBuf;

use anyhow::{Context, Result, bail};

use cbdam_builder::assign::AssignedGeoRef;
use cbdam_builder::plan::default_memory_limit;
use cbdam_builder::planet_verify::compare_planet_within;
use cbdam_builder::tiles::{Tile, expand_inputs};
use cbdam_builder::verify::{compare_colour, compare_dem, compare_tiles_with, one_file_in_blocks};
use cbdam_codec::hierarchy::{BlockPlan, RepoKind, VerifyReport};
use cbdam_codec::repository::Repository;
use clap::Args;

use crate::flags;

/// Check every checksum, decode everything and compare with the input DEM.
#[derive(Args, Debug)]
pub struct VerifyArgs {
    /// Repository file.
    repo: PathBuf,
    /// The input DEM(s), in the order given to `build`: files, directories, globs, @LIST files
    /// or GDAL VRTs of tiles, as `build` takes them.
    #[arg(long, required = true, num_args = 1..)]
    against: Vec<PathBuf>,
    /// Memory to stay within (e.g. 2G, 512M; default half of RAM): a plane from several
    /// inputs, or from one too large to decode whole (26 bytes a sample), is decoded block by
    /// block, the inputs' lattice kept in temporary files above it; a planet whose lattice does
    /// not fit (24 bytes a point) is compared block by block as the build encodes it, the
    /// decoded finest level on disk only while an input still needs it (docs/PLANET.md).
    #[arg(long, value_name = "SIZE")]
    memory_limit: Option<flags::ByteSize>,
    /// Decode blocks of this plan (testing).
    #[arg(long, value_name = "CUT,SIDE", hide = true, value_parser = crate::build::parse_block_plan)]
    block_plan: Option<cbdam_codec::hierarchy::BlockPlan>,
    #[command(flatten)]
    georef: flags::GeorefArgs,
}

/// A colour repository against its image: every level of Y, Co, Cg within `k`, and every
/// decoded R, G, B within the tolerance (`--max-error`, levels).
fn verify_colour_repo(repo: &Repository, args: &VerifyArgs) -> Result<()> {
    let [against] = args.against.as_slice() else {
        bail!(
            "a colour repository is checked against its one image, not {} files",
            args.against.len()
        );
    };
    let c = compare_colour(repo, against)?;
    let report = &c.report;
    println!(
        "level  diamonds  max error Y / Co / Cg (levels, bound {})",
        c.k
    );
    for l in 0..report.channels[0].levels.len() {
        let [y, co, cg] = &report.channels;
        println!(
            "{:>5}  {:>8}  {} / {} / {}",
            l,
            y.levels[l].diamonds,
            y.levels[l].max_error,
            co.levels[l].max_error,
            cg.levels[l].max_error
        );
    }
    println!(
        "finest level against {}: max error R {} G {} B {} levels (tolerance {}, derived bound \
         {:?})",
        against.display(),
        report.rgb_max[0],
        report.rgb_max[1],
        report.rgb_max[2],
        c.epsilon,
        report.rgb_bound
    );
    c.check()?;
    println!("OK");
    Ok(())
}

/// Several inputs, or one too large to decode whole: compared with the build's lattice, rebuilt
/// from them, and the hierarchy decoded block by block.
fn verify_tiles(
    repo: &Repository,
    tiles: &[Tile],
    limit: u64,
    block_plan: Option<BlockPlan>,
) -> Result<()> {
    let c = compare_tiles_with(repo, tiles, limit, block_plan)?;
    if let Some(plan) = c.blocks {
        let layout = repo.head().params().layout();
        println!(
            "decoded in {} block(s) of {} lattice points square, levels {} and finer \
             (the coarser ones over the whole domain)",
            plan.blocks(layout).len(),
            plan.block_side,
            plan.cut_level
        );
    }
    print_levels(&c.levels, repo.head().plan().unit);
    for input in &c.inputs {
        println!(
            "{}: {} winning samples (stride {}), max error {:.6} m",
            input.path.display(),
            input.winning,
            input.stride,
            input.max_error
        );
    }
    println!(
        "nodata mask: {} lattice points with data reached, {} mismatches",
        c.reached_valid, c.mask_mismatch_count
    );
    c.check()?;
    println!("OK");
    Ok(())
}

pub fn run(args: &VerifyArgs) -> Result<()> {
    let repo =
        Repository::open(&args.repo).with_context(|| format!("opening {}", args.repo.display()))?;
    repo.check_all()
        .with_context(|| format!("checking {}", args.repo.display()))?;
    repo.release_pages();
    if repo.head().kind() == RepoKind::Colour {
        return verify_colour_repo(&repo, args);
    }
    // Directories, globs, @lists and VRTs are expanded as `cbdam build` expands them.
    let tiles = expand_inputs(&args.against)?;
    let assign = args.georef.assigned()?;
    if repo.head().params().domain.cube().is_some() {
        let limit = args.memory_limit.map_or_else(default_memory_limit, |b| b.0);
        return verify_planet_repo(&repo, &tiles, assign.as_ref(), limit);
    }
    if assign.is_some() {
        bail!(
            "--bounds and --crs place a planet's input; {} is planar, compared sample by sample \
             with its inputs wherever they lie",
            args.repo.display()
        );
    }
    let limit = args.memory_limit.map_or_else(default_memory_limit, |b| b.0);
    let against = match tiles.as_slice() {
        [Tile { path, vrt: None }]
            if args.block_plan.is_none() && !one_file_in_blocks(&repo, path, limit) =>
        {
            path
        }
        several => return verify_tiles(&repo, several, limit, args.block_plan),
    };
    let c = compare_dem(&repo, against)?;
    print_levels(&c.levels, repo.head().plan().unit);
    println!(
        "nodata mask: {} of {} samples without data in {}, {} mismatches",
        c.nodata,
        c.samples,
        against.display(),
        c.mask_mismatches.len()
    );
    c.check_mask()?;
    println!(
        "finest level against {}: max error {:.6} m (tolerance {} m, guaranteed {}), RMS \
         error {:.6} m{}",
        against.display(),
        c.max_error,
        c.epsilon,
        repo.head().plan().bound_text(),
        c.rms_error,
        c.rms_bound
            .map_or(String::new(), |b| format!(" (bound {b} m)"))
    );
    c.check_error()?;
    println!("OK");
    Ok(())
}

/// A planet against the inputs it was built from: every level against the resampled lattice,
/// then the lattice and the decoded surface against each input's samples.
fn verify_planet_repo(
    repo: &Repository,
    tiles: &[Tile],
    assign: Option<&AssignedGeoRef>,
    limit: u64,
) -> Result<()> {
    let c = compare_planet_within(repo, tiles, repo.head().nodata(), assign, limit)?;
    if let Some(b) = c.blocks {
        println!(
            "decoded in {} block(s) of lattice tiles, the levels above them over the whole \
             planet; the decoded finest level: {} bytes written to temporary files, at most {} \
             held at once ({} at the end)",
            b.blocks, b.decoded_written, b.decoded_peak, b.decoded_at_end
        );
    }
    print_levels(&c.report, repo.head().plan().unit);
    println!(
        "every level against the resampled lattice: max error {} units, bound {} ({} m)",
        c.report.max_error(),
        c.report.bound,
        c.max_error
    );
    for (r, e) in c.resampling.iter().zip(&c.end_to_end) {
        println!(
            "{}: {} of {} samples compared; resampling error (lattice − samples) max {:.3} m, \
             rms {:.3} m; decoded surface − samples max {:.3} m, rms {:.3} m (at most {:.3} m)",
            r.path.display(),
            r.compared,
            r.samples,
            r.max_error,
            r.rms_error,
            e.max_error,
            e.rms_error,
            r.max_error + c.max_error
        );
    }
    c.check()?;
    println!("OK");
    Ok(())
}

fn print_levels(report: &VerifyReport, unit: f64) {
    println!("level  diamonds     vertices  max error (units)  max error (m)");
    for l in &report.levels {
        println!(
            "{:>5}  {:>8}  {:>11}  {:>17}  {:.6}",
            l.level,
            l.diamonds,
            l.vertices,
            l.max_error,
            f64::from(l.max_error) * unit
        );
    }
}
