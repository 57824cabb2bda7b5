//! `cbdam inspect`: what a repository holds.

use anyhow::{Context, Result};
use cbdam_codec::repository::{Repository, Section};
use serde_json::json;

use crate::InspectArgs;

pub fn run(args: &InspectArgs) -> Result<()> {
    let repo =
        Repository::open(&args.repo).with_context(|| format!("opening {}", args.repo.display()))?;
    let p = repo.params();
    let plan = repo.plan();
    let finest = p.layout.finest_level();
    // Per level: records, bytes, object-space error range in units.
    let mut levels: Vec<(usize, u64, u32, u32)> =
        vec![(0, 0, u32::MAX, 0); usize::from(finest) + 1];
    for e in repo.entries() {
        let l = &mut levels[usize::from(e.id.level)];
        l.0 += 1;
        l.1 += u64::from(e.length);
        l.2 = l.2.min(e.object_error);
        l.3 = l.3.max(e.object_error);
    }
    let samples = u64::from(p.data_width) * u64::from(p.data_height);
    let bits = repo.file_len() as f64 * 8.0 / samples as f64;
    let overhead = repo.file_len()
        - repo.section_len(Section::Roots)
        - repo.section_len(Section::Index)
        - repo.section_len(Section::Records);
    // Records whose residuals are all zero: smooth terrain has many at coarse tolerances.
    let empty = repo.entries().iter().filter(|e| e.length == 0).count();
    let metres = |u: u32| f64::from(u) * plan.unit;
    let err_lo = repo
        .entries()
        .iter()
        .map(|e| e.object_error)
        .chain([repo.leaf_error()])
        .min()
        .unwrap_or(0);
    let err_hi = repo
        .entries()
        .iter()
        .map(|e| e.object_error)
        .chain([repo.leaf_error()])
        .max()
        .unwrap_or(0);
    let geo = repo.georef().map(|g| {
        json!({
            "epsg": g.epsg, "origin_x": g.origin_x, "origin_y": g.origin_y,
            "pixel_x": g.pixel_x, "pixel_y": g.pixel_y,
            "pixel_is": if g.pixel_is_area { "area" } else { "point" },
        })
    });
    if args.json {
        let lv: Vec<_> = levels
            .iter()
            .enumerate()
            .map(|(i, l)| {
                json!({
                    "level": i, "records": l.0, "bytes": l.1,
                    "object_error_min_m": if l.0 > 0 { Some(metres(l.2)) } else { None },
                    "object_error_max_m": if l.0 > 0 { Some(metres(l.3)) } else { None },
                })
            })
            .collect();
        let v = json!({
            "file_bytes": repo.file_len(),
            "diamond_size": p.layout.n(),
            "level_pairs": p.layout.k(),
            "roots": [p.layout.roots_x(), p.layout.roots_y()],
            "alpha": if p.alpha == cbdam_codec::lifting::Alpha::One { "1" } else { "0.5" },
            "coder": p.coder.name(),
            "k": p.quantizer.k(),
            "root_k": p.root_quantizer.k(),
            "data_width": p.data_width,
            "data_height": p.data_height,
            "unit_m": plan.unit,
            "offset_m": plan.offset,
            "max_error_requested_m": plan.epsilon,
            "max_error_guaranteed_m": plan.max_error(),
            "representation_error_m": plan.representation_error,
            "lattice": plan.lattice,
            "nodata": repo.nodata(),
            "georef": geo,
            "records": repo.entries().len(),
            "empty_records": empty,
            "roots_bytes": repo.section_len(Section::Roots),
            "index_bytes": repo.section_len(Section::Index),
            "records_bytes": repo.section_len(Section::Records),
            "container_overhead_bytes": overhead,
            "bits_per_sample": bits,
            "object_error_range_m": [metres(err_lo), metres(err_hi)],
            "leaf_error_m": metres(repo.leaf_error()),
            "levels": lv,
        });
        println!("{}", serde_json::to_string_pretty(&v)?);
        return Ok(());
    }
    println!("repository      {}", args.repo.display());
    println!("file            {} bytes", repo.file_len());
    println!(
        "data            {}×{} samples, {:.4} bits/sample",
        p.data_width, p.data_height, bits
    );
    println!(
        "hierarchy       N = {}, K = {} (levels 0…{finest}), {}×{} roots, α = {}, {} coder",
        p.layout.n(),
        p.layout.k(),
        p.layout.roots_x(),
        p.layout.roots_y(),
        if p.alpha == cbdam_codec::lifting::Alpha::One {
            "1"
        } else {
            "½"
        },
        p.coder.name()
    );
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
    println!(
        "max error       {} m requested, {} m guaranteed",
        plan.epsilon,
        plan.max_error()
    );
    match repo.georef() {
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
    println!(
        "nodata          {}",
        repo.nodata().map_or("none".to_string(), |v| v.to_string())
    );
    println!(
        "sections        roots {} B, index {} B, records {} B, header + checksums {} B",
        repo.section_len(Section::Roots),
        repo.section_len(Section::Index),
        repo.section_len(Section::Records),
        overhead
    );
    println!("records         {} ({empty} empty)", repo.entries().len());
    println!(
        "object error    {} … {} m (finest level {} m)",
        metres(err_lo),
        metres(err_hi),
        metres(repo.leaf_error())
    );
    println!("level  records        bytes   object error (m)");
    for (i, l) in levels.iter().enumerate() {
        if l.0 == 0 {
            println!("{i:>5}  {:>7}  {:>11}   -", 0, 0);
        } else {
            println!(
                "{i:>5}  {:>7}  {:>11}   {} … {}",
                l.0,
                l.1,
                metres(l.2),
                metres(l.3)
            );
        }
    }
    Ok(())
}
