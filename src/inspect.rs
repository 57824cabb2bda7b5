//! `cbdam inspect`: what a repository holds.

use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use cbdam_codec::hierarchy::mask::count_valid_samples;
use cbdam_codec::repository::{Repository, Section};
use cbdam_server::describe::Summary;
use cbdam_server::summarize;
use clap::Args;

/// Print a repository's header, per-level record counts and sizes, and error range.
#[derive(Args, Debug)]
pub struct InspectArgs {
    /// Repository file.
    repo: PathBuf,
    /// Machine-readable output.
    #[arg(long)]
    json: bool,
}

/// Rewrite a repository of an older format version in the current one, 3 (from version 1: a
/// range-coded record index and the compact header; from version 2: the compact header; both
/// smaller on smooth terrain); heights, records and errors are unchanged. The output is written
/// atomically and may be the input itself.
#[derive(Args, Debug)]
pub struct UpgradeArgs {
    /// Repository file to read.
    repo: PathBuf,
    /// Where to write the upgraded repository (may be the input).
    #[arg(short, long)]
    output: PathBuf,
}

/// `cbdam upgrade`: the repository as the current writer writes it. The file's content is the
/// encoder's output as read back (`to_encoded`, every record checked), so this is a rewrite of
/// the containers, never a re-encode.
pub fn upgrade(args: &UpgradeArgs) -> Result<()> {
    let repo =
        Repository::open(&args.repo).with_context(|| format!("opening {}", args.repo.display()))?;
    let from = repo.head().format_version();
    let encoded = repo
        .to_encoded()
        .with_context(|| format!("reading the records of {}", args.repo.display()))?;
    let (plan, georef, nodata) = (
        *repo.head().plan(),
        repo.head().georef().cloned(),
        repo.head().nodata(),
    );
    let before = repo.head().file_len();
    // Unmap before writing: the output may replace the input.
    drop(repo);
    cbdam_codec::repository::write_repository(
        &args.output,
        &encoded,
        &plan,
        georef.as_ref(),
        nodata,
    )
    .with_context(|| format!("writing {}", args.output.display()))?;
    let after = std::fs::metadata(&args.output)
        .with_context(|| format!("reading back {}", args.output.display()))?
        .len();
    println!(
        "{}: format version {from} → {}, {before} → {after} bytes",
        args.output.display(),
        cbdam_codec::repository::FORMAT_VERSION
    );
    Ok(())
}

/// The lattice points of `repo` that hold data, of `samples`: all of them without a nodata mask;
/// with one, the count reads (and checks) the records.
fn count_valid(repo: &Repository, path: &Path, samples: u64) -> Result<u64> {
    Ok(if repo.head().params().nodata_mask {
        let records = repo
            .head()
            .entries()
            .iter()
            .map(|e| Ok((e.id, repo.record(e.id)?)))
            .collect::<Result<Vec<_>, cbdam_codec::CodecError>>()
            .with_context(|| format!("reading the records of {}", path.display()))?;
        count_valid_samples(repo.head().params(), repo.head().root_bytes(), records)
            .with_context(|| format!("reading the nodata mask of {}", path.display()))?
    } else {
        samples
    })
}

/// The text description's first part: the file, its kind and domain, the data and the hierarchy.
fn print_layout(repo: &Repository, path: &Path, s: &Summary) {
    let p = repo.head().params();
    let finest = p.layout().finest_level();
    let bits = s.bits_per_sample;
    println!("repository      {}", path.display());
    println!("format          version {}", repo.head().format_version());
    println!("kind            {}", p.kind.name());
    println!(
        "domain          {}",
        match p.domain.kind() {
            cbdam_codec::geometry::DomainKind::Planar => "planar, 1 face".to_string(),
            cbdam_codec::geometry::DomainKind::CubeSphere => format!(
                "cube-sphere, {} faces, WGS84 ellipsoid, sigmoid cube map (docs/PLANET.md)",
                p.domain.faces()
            ),
        }
    );
    if let Some(pv) = repo.head().provenance() {
        println!("vertical datum  {}", pv.vertical_datum.name());
        println!(
            "resampling      lattice − input samples: max {:.3} m, rms {:.3} m (the bound below \
             holds against the lattice)",
            pv.resampling_max, pv.resampling_rms
        );
    }
    println!("file            {} bytes", repo.head().file_len());
    match p.domain.cube() {
        None => println!(
            "data            {}×{} samples, {:.4} bits/sample",
            p.domain.data().width,
            p.domain.data().height,
            bits
        ),
        Some(_) => println!(
            "data            6 faces of {}×{} points, {} distinct lattice points, {:.4} bits/point",
            p.domain.data().width,
            p.domain.data().height,
            p.domain.lattice_points(),
            bits
        ),
    }
    println!(
        "hierarchy       N = {}, K = {} (levels 0…{finest}), {}×{} roots, α = {}, {} coder",
        p.layout().n(),
        p.layout().k(),
        p.layout().root_counts().0,
        p.layout().root_counts().1,
        if p.alpha == cbdam_codec::lifting::Alpha::One {
            "1"
        } else {
            "½"
        },
        p.coder.name()
    );
}

/// The georeferencing lines of the text description: EPSG, origin and pixel, and the start of
/// a WKT definition.
fn print_georef(repo: &Repository) {
    match repo.head().georef() {
        Some(g) => println!(
            "georeference    EPSG {}, origin ({}, {}), pixel {} × {}, pixel is {}",
            g.epsg.map_or("unknown".to_string(), |c| c.to_string()),
            g.origin_x,
            g.origin_y,
            g.pixel_x,
            g.pixel_y,
            if g.pixel_is_area { "area" } else { "point" }
        ),
        None => println!("georeference    none"),
    }
    if let Some(wkt) = repo.head().georef().and_then(|g| g.wkt.as_deref()) {
        // The definition's name is what a reader recognises; the whole is in --json.
        let head: String = wkt.chars().take(72).collect();
        let more = if head.len() < wkt.len() { "…" } else { "" };
        println!("crs (wkt)       {head}{more} ({} bytes)", wkt.len());
    }
}

/// The quantization and error-bound lines of the text description.
fn print_quantization(repo: &Repository) {
    let (p, plan) = (repo.head().params(), repo.head().plan());
    println!(
        "quantization    unit {} m, offset {} m, k = {} (root k = {}), {}",
        plan.unit,
        plan.offset,
        p.quantizer.k(),
        p.root_quantizer.k(),
        if plan.lattice {
            format!(
                "lattice data (representation error {} m)",
                plan.representation_error
            )
        } else {
            "pre-quantized float data".to_string()
        }
    );
    if p.kind == cbdam_codec::hierarchy::RepoKind::Colour {
        println!(
            "max error       {} levels per R, G, B component (YCoCg-R, k = {} per channel: \
             R, G, B within {:?}); values below are colour levels",
            plan.epsilon,
            p.quantizer.k(),
            cbdam_codec::colour::ycocg::rgb_bound(p.quantizer.k() as u32)
        );
        return;
    }
    match plan.rms {
        None => println!(
            "max error       {} m requested, {} guaranteed",
            plan.epsilon,
            plan.bound_text()
        ),
        Some(r) => {
            println!(
                "max error       {} guaranteed (the quantizer --rms-error chose)",
                plan.bound_text()
            );
            println!(
                "rms error       {} m bound, {} m measured by the build (finest level, every \
                 valid sample)",
                r.target, r.measured
            );
        }
    }
}

/// The text description's second part: quantization, error bound, georeferencing, nodata,
/// sections, records and the object error of every level.
fn print_coding(repo: &Repository, s: &Summary, samples: u64, valid: u64) {
    let (p, plan) = (repo.head().params(), repo.head().plan());
    let nodata_fraction = 1.0 - valid as f64 / samples as f64;
    let metres = |u: u32| f64::from(u) * plan.unit;
    let (err_lo, err_hi) = s.object_error_range;
    let overhead = s.container_overhead;
    let empty = s.empty_records;
    print_quantization(repo);
    print_georef(repo);
    println!(
        "nodata          value {}, {} of {samples} samples ({:.2} %) without data{}",
        repo.head()
            .nodata()
            .map_or("none".to_string(), |v| v.to_string()),
        samples - valid,
        100.0 * nodata_fraction,
        if p.nodata_mask {
            ", per-sample mask stored"
        } else {
            ""
        }
    );
    println!(
        "sections        roots {} B, index {} B, records {} B, header + checksums {} B",
        repo.head().section_len(Section::Roots),
        repo.head().section_len(Section::Index),
        repo.head().section_len(Section::Records),
        overhead
    );
    println!(
        "records         {} ({empty} empty)",
        repo.head().entries().len()
    );
    println!(
        "object error    {} … {} m (finest level {} m)",
        metres(err_lo),
        metres(err_hi),
        metres(repo.head().leaf_error())
    );
    println!("level  records        bytes   object error (m)");
    for (i, l) in s.levels.iter().enumerate() {
        if l.records == 0 {
            println!("{i:>5}  {:>7}  {:>11}   -", 0, 0);
        } else {
            println!(
                "{i:>5}  {:>7}  {:>11}   {} … {}",
                l.records,
                l.bytes,
                metres(l.object_error_min),
                metres(l.object_error_max)
            );
        }
    }
}

pub fn run(args: &InspectArgs) -> Result<()> {
    let repo =
        Repository::open(&args.repo).with_context(|| format!("opening {}", args.repo.display()))?;
    // Distinct lattice points that can hold data (a planet's shared edge points once).
    let samples = repo.head().params().domain.lattice_points();
    let valid = count_valid(&repo, &args.repo, samples)?;
    let nodata_fraction = 1.0 - valid as f64 / samples as f64;
    if args.json {
        // The same description the server's meta endpoint starts from.
        let mut v = cbdam_server::describe(&repo);
        v["nodata_mask"] = repo.head().params().nodata_mask.into();
        v["nodata_samples"] = (samples - valid).into();
        v["nodata_fraction"] = nodata_fraction.into();
        if let Some(r) = repo.head().plan().rms {
            v["rms_error_bound_m"] = r.target.into();
            v["rms_error_measured_m"] = r.measured.into();
        }
        println!("{}", serde_json::to_string_pretty(&v)?);
        return Ok(());
    }
    let summary = summarize(&repo);
    print_layout(&repo, &args.repo, &summary);
    print_coding(&repo, &summary, samples, valid);
    Ok(())
}
