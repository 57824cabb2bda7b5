//! `cbdam verify`: every checksum, every level, every sample.

use anyhow::{Context, Result, bail};
use std::path::PathBuf;

use cbdam_codec::colour::verify_colour;
use cbdam_codec::hierarchy::resolution::{COARSE_ONLY, HOLE};
use cbdam_codec::hierarchy::{
    Reached, RepoKind, VerifyReport, reconstruct_finest_with_validity, reconstruct_reached, verify,
};
use cbdam_codec::input::{Format, Limits, ReadOptions, read_dem, read_rgb};
use cbdam_codec::quant::HeightGrid;
use cbdam_codec::repository::Repository;

use crate::VerifyArgs;
use crate::mosaic::mosaic;

/// A colour repository against its image: every level of Y, Co, Cg within `k`, and every
/// decoded R, G, B within the tolerance (`--max-error`, levels).
fn verify_colour_repo(repo: &Repository, args: &VerifyArgs) -> Result<()> {
    let [against] = args.against.as_slice() else {
        bail!(
            "a colour repository is checked against its one image, not {} files",
            args.against.len()
        );
    };
    let img = read_rgb(against, &Limits::default())
        .with_context(|| format!("reading {}", against.display()))?;
    let encoded = repo.to_encoded()?;
    let report = verify_colour(&encoded, &img)
        .with_context(|| format!("checking against {}", against.display()))?;
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
        against.display(),
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
    let against = match args.against.as_slice() {
        [one] => one,
        several => return verify_mosaic(&repo, several, &opts),
    };
    // A raw float32 file has no size of its own: it is the repository's (and a file of another
    // length is refused by the reader).
    let opts = if crate::build::is_raw_path(against) {
        ReadOptions {
            format: Some(Format::RawF32 {
                width: p.domain.data().width as usize,
                height: p.domain.data().height as usize,
            }),
            ..opts
        }
    } else {
        opts
    };
    let dem = read_dem(against, &opts).with_context(|| format!("reading {}", against.display()))?;
    if (dem.width, dem.height)
        != (
            p.domain.data().width as usize,
            p.domain.data().height as usize,
        )
    {
        bail!(
            "{} is {}×{} samples, the repository was built from {}×{}",
            against.display(),
            dem.width,
            dem.height,
            p.domain.data().width,
            p.domain.data().height
        );
    }
    let grid = HeightGrid::from_dem(&dem, &plan).with_context(|| {
        format!(
            "mapping {} onto the repository's height lattice",
            against.display()
        )
    })?;
    let encoded = repo.to_encoded()?;
    let report = verify(&encoded, &grid).context("decoding the hierarchy")?;
    print_levels(&report, plan.unit);
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
        against.display(),
        wrong.len()
    );
    if let Some(&i) = wrong.first() {
        bail!(
            "nodata mask disagrees with the input at {} samples, first at column {}, row {} \
             (repository says {}, input says {})",
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
        against.display(),
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

/// Several inputs: rebuilds the build's lattice from them ([`crate::mosaic`]) and checks every
/// winning sample of every input, the nodata mask wherever the hierarchy reaches, and that every
/// winning sample is reached at all.
fn verify_mosaic(repo: &Repository, paths: &[PathBuf], opts: &ReadOptions) -> Result<()> {
    let p = *repo.params();
    let plan = *repo.plan();
    let m = mosaic(paths, opts, u64::MAX)?;
    if (m.width, m.height)
        != (
            p.domain.data().width as usize,
            p.domain.data().height as usize,
        )
    {
        bail!(
            "the inputs make a {}×{} lattice, the repository was built from {}×{}",
            m.width,
            m.height,
            p.domain.data().width,
            p.domain.data().height
        );
    }
    let grid = HeightGrid::from_source(&m, &plan)
        .context("mapping the inputs onto the repository's height lattice")?;
    let encoded = repo.to_encoded()?;
    let report = verify(&encoded, &grid).context("decoding the hierarchy")?;
    print_levels(&report, plan.unit);
    let (values, state) = reconstruct_reached(&encoded)?;
    let mut max_err = vec![0f64; m.inputs.len()];
    let mut count = vec![0usize; m.inputs.len()];
    let mut unreached = Vec::new();
    let mut mask_wrong = Vec::new();
    let mut worst: Option<(f64, usize)> = None;
    for (i, (&src, &st)) in m.source.iter().zip(&state).enumerate() {
        match (src, st) {
            (HOLE, Reached::Valid) | (COARSE_ONLY, Reached::Invalid) => mask_wrong.push(i),
            (HOLE | COARSE_ONLY, _) => {}
            (_, Reached::No) => unreached.push(i),
            (_, Reached::Invalid) => mask_wrong.push(i),
            (k, Reached::Valid) => {
                let e = (plan.metres(values[i]) - m.value(i)).abs();
                let k = usize::from(k);
                max_err[k] = max_err[k].max(e);
                count[k] += 1;
                if worst.is_none_or(|(w, _)| e > w) {
                    worst = Some((e, i));
                }
            }
        }
    }
    let w = m.width;
    for (k, input) in m.inputs.iter().enumerate() {
        println!(
            "{}: {} winning samples (stride {}), max error {:.6} m",
            input.path.display(),
            count[k],
            1u32 << input.log2,
            max_err[k]
        );
    }
    println!(
        "nodata mask: {} lattice points with data reached, {} mismatches",
        state.iter().filter(|&&s| s == Reached::Valid).count(),
        mask_wrong.len()
    );
    if let Some(&i) = mask_wrong.first() {
        bail!(
            "nodata mask disagrees with the inputs at {} lattice points, first at column {}, \
             row {} (repository says {:?}, inputs say {})",
            mask_wrong.len(),
            i % w,
            i / w,
            state[i],
            if m.source[i] == HOLE {
                "no data"
            } else {
                "data"
            }
        );
    }
    if let Some(&i) = unreached.first() {
        bail!(
            "{} winning samples are never reconstructed, first at lattice column {}, row {}",
            unreached.len(),
            i % w,
            i / w
        );
    }
    if !report.within_bound() {
        bail!(
            "L∞ bound violated: {} units on some level, bound {} units",
            report.max_error(),
            report.bound
        );
    }
    if let Some((e, i)) = worst
        && e > plan.epsilon * (1.0 + 1e-12)
    {
        bail!(
            "lattice point at column {}, row {} (from {}) is off by {e} m, above the {} m \
             tolerance",
            i % w,
            i / w,
            m.inputs[usize::from(m.source[i])].path.display(),
            plan.epsilon
        );
    }
    println!("OK");
    Ok(())
}
