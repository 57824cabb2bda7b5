//! `cbdam verify`: every checksum, every level, every sample.

use anyhow::{Context, Result, bail};
use cbdam_codec::colour::verify_colour;
use cbdam_codec::hierarchy::{RepoKind, reconstruct_finest_with_validity, verify};
use cbdam_codec::input::{Limits, ReadOptions, read_dem, read_rgb};
use cbdam_codec::quant::HeightGrid;
use cbdam_codec::repository::Repository;

use crate::VerifyArgs;

/// A colour repository against its image: every level of Y, Co, Cg within `k`, and every
/// decoded R, G, B within the tolerance (`--max-error`, levels).
fn verify_colour_repo(repo: &Repository, args: &VerifyArgs) -> Result<()> {
    let img = read_rgb(&args.against, &Limits::default())
        .with_context(|| format!("reading {}", args.against.display()))?;
    let encoded = repo.to_encoded()?;
    let report = verify_colour(&encoded, &img)
        .with_context(|| format!("checking against {}", args.against.display()))?;
    let k = repo.params().quantizer.k();
    println!("level  diamonds  max error Y / Co / Cg (levels, bound {k})");
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
    let eps = repo.plan().epsilon;
    println!(
        "finest level against {}: max error R {} G {} B {} levels (tolerance {eps}, derived bound \
         {:?})",
        args.against.display(),
        report.rgb_max[0],
        report.rgb_max[1],
        report.rgb_max[2],
        report.rgb_bound
    );
    if let Some(c) = report.channels.iter().position(|c| !c.within_bound()) {
        bail!(
            "L∞ bound violated in channel {}: {} levels, bound {k}",
            ["Y", "Co", "Cg"][c],
            report.channels[c].max_error()
        );
    }
    if report.rgb_max.iter().any(|&e| f64::from(e) > eps) {
        bail!(
            "RGB error {:?} above the {eps}-level tolerance",
            report.rgb_max
        );
    }
    println!("OK");
    Ok(())
}

pub fn run(args: &VerifyArgs) -> Result<()> {
    let repo =
        Repository::open(&args.repo).with_context(|| format!("opening {}", args.repo.display()))?;
    repo.check_all()
        .with_context(|| format!("checking {}", args.repo.display()))?;
    if repo.kind() == RepoKind::Colour {
        return verify_colour_repo(&repo, args);
    }
    let p = *repo.params();
    let plan = *repo.plan();
    // Read the input the way the build did: its nodata value was recorded in the header.
    let opts = ReadOptions {
        nodata: repo.nodata(),
        ..ReadOptions::default()
    };
    let dem = read_dem(&args.against, &opts)
        .with_context(|| format!("reading {}", args.against.display()))?;
    if (dem.width, dem.height) != (p.data_width as usize, p.data_height as usize) {
        bail!(
            "{} is {}×{} samples, the repository was built from {}×{}",
            args.against.display(),
            dem.width,
            dem.height,
            p.data_width,
            p.data_height
        );
    }
    let grid = HeightGrid::from_dem(&dem, &plan).with_context(|| {
        format!(
            "mapping {} onto the repository's height lattice",
            args.against.display()
        )
    })?;
    let encoded = repo.to_encoded()?;
    let report = verify(&encoded, &grid).context("decoding the hierarchy")?;
    println!("level  diamonds     vertices  max error (units)  max error (m)");
    for l in &report.levels {
        println!(
            "{:>5}  {:>8}  {:>11}  {:>17}  {:.6}",
            l.level,
            l.diamonds,
            l.vertices,
            l.max_error,
            f64::from(l.max_error) * plan.unit
        );
    }
    // Against the samples as stored, in metres: what the user was promised.
    let (finest, valid) = reconstruct_finest_with_validity(&encoded)?;
    // The nodata mask must state exactly which samples had data: a sample drawn that had none
    // shows invented surface, one hidden that had data loses it.
    let wrong: Vec<usize> = (0..valid.len())
        .filter(|&i| valid[i] != grid.valid[i])
        .collect();
    let nodata = grid.valid.iter().filter(|v| !**v).count();
    println!(
        "nodata mask: {nodata} of {} samples without data in {}, {} mismatches",
        grid.valid.len(),
        args.against.display(),
        wrong.len()
    );
    if let Some(&i) = wrong.first() {
        bail!(
            "nodata mask disagrees with the input at {} samples, first at column {}, row {}              (repository says {}, input says {})",
            wrong.len(),
            i % dem.width,
            i / dem.width,
            if valid[i] { "data" } else { "nodata" },
            if grid.valid[i] { "data" } else { "nodata" }
        );
    }
    let mut max_err = 0f64;
    let mut worst = 0usize;
    for (i, &n) in finest.iter().enumerate() {
        if grid.valid[i] {
            let e = (plan.metres(n) - dem.values[i]).abs();
            if e > max_err {
                max_err = e;
                worst = i;
            }
        }
    }
    println!(
        "finest level against {}: max error {max_err:.6} m (tolerance {} m, guaranteed {} m)",
        args.against.display(),
        plan.epsilon,
        plan.max_error()
    );
    if !report.within_bound() {
        bail!(
            "L∞ bound violated: {} units on some level, bound {} units",
            report.max_error(),
            report.bound
        );
    }
    // f64 evaluation of offset + n·u is good to ~1e-16 relative; the bound itself was checked
    // exactly in integers above.
    if max_err > plan.epsilon * (1.0 + 1e-12) {
        bail!(
            "sample at column {}, row {} is off by {max_err} m, above the {} m tolerance",
            worst % dem.width,
            worst / dem.width,
            plan.epsilon
        );
    }
    println!("OK");
    Ok(())
}
