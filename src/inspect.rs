//! `cbdam inspect`: what a repository holds, gathered once into an [`InspectReport`] and
//! written as text or as JSON.

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::{Context, Result};
use cbdam_codec::geometry::DomainKind;
use cbdam_codec::hierarchy::RepoKind;
use cbdam_codec::hierarchy::mask::count_valid_samples;
use cbdam_codec::lifting::Alpha;
use cbdam_codec::repository::{Repository, Section, decoded_digest};
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
    /// Also decode every record and print a digest of the decoded surface (64-bit FNV-1a over
    /// every diamond's grid in the walk's order): equal digests mean two decoders (or two
    /// coders of one surface) decode to the same samples, bit for bit.
    #[arg(long)]
    digest: bool,
}

pub fn run(args: &InspectArgs) -> Result<()> {
    let repo =
        Repository::open(&args.repo).with_context(|| format!("opening {}", args.repo.display()))?;
    let report = InspectReport::gather(&repo, &args.repo)?;
    let digest = match args.digest {
        true => Some(
            decoded_digest(&repo).with_context(|| format!("decoding {}", args.repo.display()))?,
        ),
        false => None,
    };
    let mut out = std::io::stdout().lock();
    if args.json {
        let mut v = report.json();
        if let Some(d) = digest {
            v["decoded_digest"] = serde_json::json!({
                "fnv1a64": format!("{:016x}", d.fnv1a64),
                "diamonds": d.diamonds,
                "samples": d.samples,
            });
        }
        writeln!(out, "{}", serde_json::to_string_pretty(&v)?)?;
    } else {
        report.write_text(&mut out)?;
        if let Some(d) = digest {
            writeln!(
                out,
                "decoded         fnv1a-64 {:016x} over {} diamonds, {} samples",
                d.fnv1a64, d.diamonds, d.samples
            )?;
        }
    }
    Ok(())
}

/// Everything `inspect` says of a repository, gathered once: the header (read through the
/// repository), the per-level summary, and how many of its lattice points hold data. Written
/// as text ([`InspectReport::write_text`]) or as JSON ([`InspectReport::json`]).
struct InspectReport<'a> {
    repo: &'a Repository,
    path: &'a Path,
    summary: Summary,
    /// Distinct lattice points that can hold data (a planet's shared edge points once).
    samples: u64,
    /// Of those, the points that hold data.
    valid: u64,
}

impl<'a> InspectReport<'a> {
    /// The report of `repo`, opened from `path`: reads (and checks) the records when there is
    /// a nodata mask, to count the points with data.
    fn gather(repo: &'a Repository, path: &'a Path) -> Result<Self> {
        let samples = repo.head().params().domain.lattice_points();
        let valid = count_valid(repo, path, samples)?;
        Ok(InspectReport {
            repo,
            path,
            summary: summarize(repo),
            samples,
            valid,
        })
    }

    /// The share of the lattice points without data.
    fn nodata_fraction(&self) -> f64 {
        1.0 - self.valid as f64 / self.samples as f64
    }

    /// The JSON form: the description the server's meta endpoint starts from, with the nodata
    /// counts and the RMS bound.
    fn json(&self) -> serde_json::Value {
        let mut v = cbdam_server::describe(self.repo);
        v["nodata_mask"] = self.repo.head().params().nodata_mask.into();
        v["nodata_samples"] = (self.samples - self.valid).into();
        v["nodata_fraction"] = self.nodata_fraction().into();
        if let Some(r) = self.repo.head().plan().rms {
            v["rms_error_bound_m"] = r.target.into();
            v["rms_error_measured_m"] = r.measured.into();
        }
        if let Some(l) = self.repo.head().params().levels {
            v["level_k"] = l.ks().into();
            v["level_max_error_m"] = self.level_max_errors().into();
        }
        v
    }

    /// The L∞ bound of each level's samples, metres, levels 0 … finest: with per-level
    /// quantizers each level's own ([`cbdam_codec::hierarchy::CodecParams::level_bound`]).
    fn level_max_errors(&self) -> Vec<f64> {
        let (p, plan) = (self.repo.head().params(), self.repo.head().plan());
        (0..=p.layout().finest_level())
            .map(|level| {
                let q = cbdam_codec::quant::Quantizer::new(p.level_bound(level))
                    .expect("a level's bound is at most the header's valid k");
                cbdam_codec::quant::QuantPlan {
                    quantizer: q,
                    ..*plan
                }
                .max_error()
            })
            .collect()
    }

    /// The text form: the layout, the coding, the georeferencing, nodata, the sections and a
    /// line per level.
    fn write_text(&self, out: &mut impl Write) -> std::io::Result<()> {
        self.write_layout(out)?;
        self.write_quantization(out)?;
        self.write_georef(out)?;
        self.write_contents(out)?;
        self.write_levels(out)
    }

    /// The file, its kind and domain, the data and the hierarchy.
    fn write_layout(&self, out: &mut impl Write) -> std::io::Result<()> {
        let head = self.repo.head();
        let p = head.params();
        let finest = p.layout().finest_level();
        writeln!(out, "repository      {}", self.path.display())?;
        writeln!(out, "format          version {}", head.format_version())?;
        writeln!(out, "kind            {}", p.kind.name())?;
        let domain = match p.domain.kind() {
            DomainKind::Planar => "planar, 1 face".to_string(),
            DomainKind::CubeSphere => format!(
                "cube-sphere, {} faces, WGS84 ellipsoid, sigmoid cube map (docs/PLANET.md)",
                p.domain.faces()
            ),
        };
        writeln!(out, "domain          {domain}")?;
        if let Some(pv) = head.provenance() {
            writeln!(out, "vertical datum  {}", pv.vertical_datum.name())?;
            writeln!(
                out,
                "resampling      lattice − input samples: max {:.3} m, rms {:.3} m (the bound \
                 below holds against the lattice)",
                pv.resampling_max, pv.resampling_rms
            )?;
        }
        writeln!(out, "file            {} bytes", head.file_len())?;
        let (width, height) = (p.domain.data().width, p.domain.data().height);
        let bits = self.summary.bits_per_sample;
        match p.domain.cube() {
            None => writeln!(
                out,
                "data            {width}×{height} samples, {bits:.4} bits/sample"
            )?,
            Some(_) => writeln!(
                out,
                "data            6 faces of {width}×{height} points, {} distinct lattice \
                 points, {bits:.4} bits/point",
                p.domain.lattice_points()
            )?,
        }
        let (roots_x, roots_y) = p.layout().root_counts();
        writeln!(
            out,
            "hierarchy       N = {}, K = {} (levels 0…{finest}), {roots_x}×{roots_y} roots, α = {}, \
             {} coder",
            p.layout().n(),
            p.layout().k(),
            if p.alpha == Alpha::One { "1" } else { "½" },
            p.coder.name()
        )
    }

    /// The quantization and the error bound (a colour repository's in colour levels).
    fn write_quantization(&self, out: &mut impl Write) -> std::io::Result<()> {
        let (p, plan) = (self.repo.head().params(), self.repo.head().plan());
        let values = if plan.lattice {
            format!(
                "lattice data (representation error {} m)",
                plan.representation_error
            )
        } else {
            "pre-quantized float data".to_string()
        };
        writeln!(
            out,
            "quantization    unit {} m, offset {} m, k = {} (root k = {}), {values}",
            plan.unit,
            plan.offset,
            p.quantizer.k(),
            p.root_quantizer.k(),
        )?;
        if p.kind == RepoKind::Colour {
            return writeln!(
                out,
                "max error       {} levels per R, G, B component (YCoCg-R, k = {} per channel: \
                 R, G, B within {:?}); values below are colour levels",
                plan.epsilon,
                p.quantizer.k(),
                cbdam_codec::colour::ycocg::rgb_bound(p.quantizer.k() as u32)
            );
        }
        match plan.rms {
            None => writeln!(
                out,
                "max error       {} m requested, {} guaranteed",
                plan.epsilon,
                plan.bound_text()
            ),
            Some(r) => {
                writeln!(
                    out,
                    "max error       {} guaranteed (the quantizer --rms-error chose)",
                    plan.bound_text()
                )?;
                writeln!(
                    out,
                    "rms error       {} m bound, {} m measured by the build (finest level, \
                     every valid sample)",
                    r.target, r.measured
                )
            }
        }
    }

    /// EPSG, origin and pixel, and the start of a WKT definition (the whole is in the JSON).
    fn write_georef(&self, out: &mut impl Write) -> std::io::Result<()> {
        let Some(g) = self.repo.head().georef() else {
            return writeln!(out, "georeference    none");
        };
        writeln!(
            out,
            "georeference    EPSG {}, origin ({}, {}), pixel {} × {}, pixel is {}",
            g.epsg.map_or("unknown".to_string(), |c| c.to_string()),
            g.origin_x,
            g.origin_y,
            g.pixel_x,
            g.pixel_y,
            if g.pixel_is_area { "area" } else { "point" }
        )?;
        if let Some(wkt) = g.wkt.as_deref() {
            // The definition's name is what a reader recognises.
            let head: String = wkt.chars().take(72).collect();
            let more = if head.len() < wkt.len() { "…" } else { "" };
            writeln!(out, "crs (wkt)       {head}{more} ({} bytes)", wkt.len())?;
        }
        Ok(())
    }

    /// Nodata, the sections, the records and the object error range.
    fn write_contents(&self, out: &mut impl Write) -> std::io::Result<()> {
        let head = self.repo.head();
        let s = &self.summary;
        let (samples, valid) = (self.samples, self.valid);
        writeln!(
            out,
            "nodata          value {}, {} of {samples} samples ({:.2} %) without data{}",
            head.nodata().map_or("none".to_string(), |v| v.to_string()),
            samples - valid,
            100.0 * self.nodata_fraction(),
            if head.params().nodata_mask {
                ", per-sample mask stored"
            } else {
                ""
            }
        )?;
        writeln!(
            out,
            "sections        roots {} B, index {} B, records {} B, header + checksums {} B",
            head.section_len(Section::Roots),
            head.section_len(Section::Index),
            head.section_len(Section::Records),
            s.container_overhead
        )?;
        writeln!(
            out,
            "records         {} ({} empty)",
            head.entries().len(),
            s.empty_records
        )?;
        let (lo, hi) = s.object_error_range;
        writeln!(
            out,
            "object error    {} … {} m (finest level {} m)",
            self.metres(lo),
            self.metres(hi),
            self.metres(head.leaf_error())
        )
    }

    /// A line per level: its records, their bytes and their object error range.
    fn write_levels(&self, out: &mut impl Write) -> std::io::Result<()> {
        if let Some(levels) = self.repo.head().params().levels {
            return self.write_levels_quantized(out, levels.ks());
        }
        writeln!(out, "level  records        bytes   object error (m)")?;
        for (i, l) in self.summary.levels.iter().enumerate() {
            if l.records == 0 {
                writeln!(out, "{i:>5}  {:>7}  {:>11}   -", 0, 0)?;
            } else {
                writeln!(
                    out,
                    "{i:>5}  {:>7}  {:>11}   {} … {}",
                    l.records,
                    l.bytes,
                    self.metres(l.object_error_min),
                    self.metres(l.object_error_max)
                )?;
            }
        }
        Ok(())
    }

    /// [`Self::write_levels`] for a repository with a quantizer per level: each level's
    /// records' `k` and the maximum error its samples are guaranteed.
    fn write_levels_quantized(&self, out: &mut impl Write, ks: &[u32]) -> std::io::Result<()> {
        writeln!(
            out,
            "level  records        bytes  records' k  max error (m)  object error (m)"
        )?;
        let bounds = self.level_max_errors();
        for (i, l) in self.summary.levels.iter().enumerate() {
            let k = ks.get(i).map_or("-".to_string(), |k| k.to_string());
            let object = if l.records == 0 {
                "-".to_string()
            } else {
                format!(
                    "{} … {}",
                    self.metres(l.object_error_min),
                    self.metres(l.object_error_max)
                )
            };
            let bound = bounds.get(i).copied().unwrap_or(f64::NAN);
            writeln!(
                out,
                "{i:>5}  {:>7}  {:>11}  {k:>10}  {bound:>13}  {object}",
                l.records, l.bytes
            )?;
        }
        Ok(())
    }

    /// Height units in metres (a colour repository's in colour levels).
    fn metres(&self, units: u32) -> f64 {
        f64::from(units) * self.repo.head().plan().unit
    }
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
