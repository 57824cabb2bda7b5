//! The `plan` file of a sharded build's work directory ([`crate::shard`]): what the steps
//! after the plan need — output path, options, quantization, georeferencing, blocks, shards —
//! one `name=value` line each, floats as their bits and text in hex, so they read back exactly.

use std::ops::Range;
use std::path::{Path, PathBuf};

use cbdam_codec::entropy::CoderKind;
use cbdam_codec::hierarchy::{BlockPlan, EncodeOptions};
use cbdam_codec::lifting::Alpha;
use cbdam_codec::quant::{QuantPlan, Quantizer};
use cbdam_codec::repository::GeoRef;

use crate::encode::ExtraLevels;
use crate::error::Result;
/// What a sharded build's steps share: read from the work directory's `plan` file.
#[derive(Clone, Debug, PartialEq)]
pub struct ShardPlan {
    /// The repository the merge writes (absolute).
    pub output: PathBuf,
    /// Samples per row and rows of the (combined) input.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// Whether the input is several inputs (a variable-resolution lattice with classes).
    pub variable: bool,
    /// Diamond grid side N.
    pub diamond_size: usize,
    /// `--extra-levels`.
    pub extra_levels: ExtraLevels,
    /// Entropy coder.
    pub coder: CoderKind,
    /// Memory limit of the build, bytes (the merge's `--extra-levels auto` retry).
    pub memory_limit: u64,
    /// The integer mapping.
    pub quant: QuantPlan,
    /// Georeferencing.
    pub georef: Option<GeoRef>,
    /// Nodata value.
    pub nodata: Option<f64>,
    /// The blocks.
    pub blocks: BlockPlan,
    /// How many blocks the plan makes.
    pub block_count: usize,
    /// How many shards (runs of consecutive blocks).
    pub shards: usize,
}

impl ShardPlan {
    /// The blocks of shard `shard` (`0 .. shards`).
    pub fn shard_blocks(&self, shard: usize) -> Range<usize> {
        let (b, s) = (self.block_count, self.shards.max(1));
        shard * b / s..(shard + 1) * b / s
    }

    /// The shard that holds `block`.
    pub(crate) fn shard_of(&self, block: usize) -> usize {
        (0..self.shards)
            .find(|&s| self.shard_blocks(s).contains(&block))
            .unwrap_or(0)
    }

    pub(crate) fn encode_options(&self) -> EncodeOptions {
        EncodeOptions {
            n: self.diamond_size,
            alpha: Alpha::One,
            coder: self.coder,
            extra_level_pairs: self.extra_levels.first(),
        }
    }

    /// The `plan` file: one `name=value` line each; floats as their bits, so they read back
    /// exactly.
    pub(crate) fn to_text(&self) -> String {
        let f = |v: f64| format!("{:016x}", v.to_bits());
        let q = &self.quant;
        let mut t = format!(
            "output={}\nwidth={}\nheight={}\nvariable={}\ndiamond_size={}\nextra_levels={}\n\
             coder={:?}\nmemory_limit={}\nunit={}\noffset={}\nk={}\nlattice={}\n\
             representation_error={}\nepsilon={}\ncut_level={}\nblock_side={}\nblocks={}\n\
             shards={}\n",
            hex(self.output.to_string_lossy().as_bytes()),
            self.width,
            self.height,
            self.variable,
            self.diamond_size,
            match self.extra_levels {
                ExtraLevels::Auto => "auto".to_string(),
                ExtraLevels::Fixed(n) => n.to_string(),
            },
            self.coder,
            self.memory_limit,
            f(q.unit),
            f(q.offset),
            q.quantizer.k(),
            q.lattice,
            f(q.representation_error),
            f(q.epsilon),
            self.blocks.cut_level,
            self.blocks.block_side,
            self.block_count,
            self.shards,
        );
        if let Some(nodata) = self.nodata {
            t += &format!("nodata={}\n", f(nodata));
        }
        if let Some(g) = &self.georef {
            t += &format!(
                "georef={} {} {} {} {} {} {}\n",
                g.epsg.map_or("-".to_string(), |e| e.to_string()),
                f(g.origin_x),
                f(g.origin_y),
                f(g.pixel_x),
                f(g.pixel_y),
                g.pixel_is_area,
                g.wkt
                    .as_deref()
                    .map_or("-".to_string(), |w| hex(w.as_bytes())),
            );
        }
        t
    }

    pub(crate) fn parse(text: &str, file: &Path) -> Result<ShardPlan> {
        let bad = |what: &str| {
            crate::BuildError::Invalid(format!(
                "{}: {what} missing or unreadable (a plan file of another cbdam version?)",
                file.display()
            ))
        };
        let value = |name: &str| {
            text.lines()
                .find_map(|l| l.strip_prefix(name)?.strip_prefix('='))
        };
        let get = |name: &str| value(name).ok_or_else(|| bad(name));
        let num = |name: &str| get(name)?.parse::<u64>().map_err(|_| bad(name));
        let float = |s: &str| u64::from_str_radix(s, 16).ok().map(f64::from_bits);
        let real = |name: &str| float(get(name)?).ok_or_else(|| bad(name));
        let text_of = |s: &str, name: &str| {
            unhex(s)
                .and_then(|b| String::from_utf8(b).ok())
                .ok_or_else(|| bad(name))
        };
        let k = get("k")?.parse::<u32>().map_err(|_| bad("k"))?;
        let quant = QuantPlan {
            unit: real("unit")?,
            offset: real("offset")?,
            quantizer: Quantizer::new(k).map_err(|_| bad("k"))?,
            lattice: get("lattice")? == "true",
            representation_error: real("representation_error")?,
            epsilon: real("epsilon")?,
            // Sharded builds bound the maximum error only.
            rms: None,
            levels: None,
        };
        let georef = match value("georef") {
            None => None,
            Some(g) => Some(parse_georef(g).ok_or_else(|| bad("georef"))?),
        };
        let coder_name = get("coder")?;
        Ok(ShardPlan {
            output: PathBuf::from(text_of(get("output")?, "output")?),
            width: num("width")? as usize,
            height: num("height")? as usize,
            variable: get("variable")? == "true",
            diamond_size: num("diamond_size")? as usize,
            extra_levels: match get("extra_levels")? {
                "auto" => ExtraLevels::Auto,
                n => ExtraLevels::Fixed(n.parse().map_err(|_| bad("extra_levels"))?),
            },
            coder: CoderKind::ALL
                .into_iter()
                .find(|c| format!("{c:?}") == coder_name)
                .ok_or_else(|| bad("coder"))?,
            memory_limit: num("memory_limit")?,
            quant,
            georef,
            nodata: match value("nodata") {
                None => None,
                Some(v) => Some(float(v).ok_or_else(|| bad("nodata"))?),
            },
            blocks: BlockPlan {
                cut_level: num("cut_level")? as u8,
                block_side: num("block_side")? as i64,
            },
            block_count: num("blocks")? as usize,
            shards: num("shards")? as usize,
        })
    }
}

/// The `georef=` line's value: EPSG, origin, pixel size (floats as bits), pixel-is-area, WKT
/// (hex); `-` for none.
fn parse_georef(g: &str) -> Option<GeoRef> {
    let p: Vec<&str> = g.split(' ').collect();
    let [epsg, ox, oy, px, py, area, wkt] = p[..] else {
        return None;
    };
    let r = |s: &str| u64::from_str_radix(s, 16).ok().map(f64::from_bits);
    Some(GeoRef {
        epsg: match epsg {
            "-" => None,
            e => Some(e.parse().ok()?),
        },
        origin_x: r(ox)?,
        origin_y: r(oy)?,
        pixel_x: r(px)?,
        pixel_y: r(py)?,
        pixel_is_area: area == "true",
        wkt: match wkt {
            "-" => None,
            w => Some(String::from_utf8(unhex(w)?).ok()?),
        },
    })
}

pub(crate) fn hex(bytes: &[u8]) -> String {
    bytes.iter().map(|b| format!("{b:02x}")).collect()
}

pub(crate) fn unhex(s: &str) -> Option<Vec<u8>> {
    if !s.len().is_multiple_of(2) {
        return None;
    }
    (0..s.len())
        .step_by(2)
        .map(|i| u8::from_str_radix(s.get(i..i + 2)?, 16).ok())
        .collect()
}
