//! The `planet` file of a sharded planet build's work directory ([`crate::planet_shard`]):
//! what every step needs to open the inputs and encode as `cbdam build --planet` would — the
//! inputs as given (absolute), each file they expand to with its size and modification time
//! (so that a step notices an input changed since the plan), and the arguments. One
//! `name=value` line each; paths in hex, floats as their bits, so they read back exactly.

use std::ops::Range;
use std::path::{Path, PathBuf};
use std::time::UNIX_EPOCH;

use cbdam_codec::entropy::CoderKind;
use cbdam_codec::quant::QuantPlan;

use crate::assign::AssignedGeoRef;
use crate::error::{Context, Result, bail};
use crate::shard_plan::{hex, unhex};
use crate::tiles::Tile;

/// What a sharded planet build's steps share.
#[derive(Clone, Debug, PartialEq)]
pub struct PlanetShardPlan {
    /// The repository the merge writes (absolute).
    pub output: PathBuf,
    /// The inputs as given, made absolute (files, directories, globs, `@list`s, VRTs).
    pub inputs: Vec<PathBuf>,
    /// Every file they expanded to at the plan: `path size modified-ns`.
    pub files: Vec<String>,
    /// `--nodata`.
    pub nodata: Option<f64>,
    /// `--bounds` and `--crs`.
    pub assign: Option<AssignedGeoRef>,
    /// Diamond grid side N.
    pub n: usize,
    /// The lattice's level pairs K.
    pub k: u32,
    /// `--max-error`, metres.
    pub max_error: f64,
    /// The inputs' height range, metres.
    pub range: (f64, f64),
    /// Entropy coder.
    pub coder: CoderKind,
    /// The build's memory limit, bytes (the caches of inputs and tiles follow it).
    pub memory_limit: u64,
    /// Blocks: one per lattice tile.
    pub block_count: usize,
    /// The fewest blocks the tiles were grouped into (`4·S` for `--shards S`, so that the
    /// shards have blocks to share; 1 otherwise).
    pub min_blocks: usize,
    /// Shards: runs of consecutive blocks.
    pub shards: usize,
}

/// `path` made absolute (an `@LIST`'s list file too) against the current directory: the
/// steps may run elsewhere.
pub(crate) fn absolute(path: &Path) -> Result<PathBuf> {
    let cwd = std::env::current_dir().context("reading the current directory")?;
    let text = path.to_string_lossy();
    Ok(match text.strip_prefix('@') {
        Some(list) => PathBuf::from(format!("@{}", cwd.join(list).display())),
        None => cwd.join(path),
    })
}

fn float(v: f64) -> String {
    format!("{:016x}", v.to_bits())
}

impl PlanetShardPlan {
    /// The `path size modified-ns` line of every tile.
    pub(crate) fn files_of(tiles: &[Tile]) -> Result<Vec<String>> {
        tiles
            .iter()
            .map(|t| {
                let m = std::fs::metadata(&t.path)
                    .with_context(|| format!("reading {}", t.path.display()))?;
                let modified = m
                    .modified()
                    .ok()
                    .and_then(|t| t.duration_since(UNIX_EPOCH).ok())
                    .map_or(0, |d| d.as_nanos());
                Ok(format!(
                    "{} {} {modified}",
                    hex(t.path.to_string_lossy().as_bytes()),
                    m.len()
                ))
            })
            .collect()
    }

    /// Refuses inputs that expand to other files than at the plan, or whose size or
    /// modification time changed since, naming the first.
    pub(crate) fn check_files(&self, tiles: &[Tile]) -> Result<()> {
        let now = Self::files_of(tiles)?;
        if now.len() != self.files.len() {
            bail!(
                "the inputs now expand to {} files where the plan read {}: plan again in a new \
                 work directory",
                now.len(),
                self.files.len()
            );
        }
        for (t, (was, is)) in tiles.iter().zip(self.files.iter().zip(&now)) {
            if was != is {
                bail!(
                    "{} changed since the plan (another file, size or modification time): plan \
                     again in a new work directory",
                    t.path.display()
                );
            }
        }
        Ok(())
    }

    /// The integer mapping `cbdam build --planet` makes of these inputs.
    pub fn quant(&self) -> Result<QuantPlan> {
        Ok(QuantPlan::new(
            self.max_error,
            None,
            self.range.0,
            self.range.1,
        )?)
    }

    /// The blocks of shard `shard`.
    pub fn shard_blocks(&self, shard: usize) -> Range<usize> {
        share(self.block_count, self.shards, shard)
    }

    /// The file's text.
    pub(crate) fn to_text(&self) -> String {
        let mut t = format!(
            "output={}\nn={}\nk={}\nmax_error={}\nlow={}\nhigh={}\ncoder={:?}\n\
             memory_limit={}\nblocks={}\nmin_blocks={}\nshards={}\n",
            hex(self.output.to_string_lossy().as_bytes()),
            self.n,
            self.k,
            float(self.max_error),
            float(self.range.0),
            float(self.range.1),
            self.coder,
            self.memory_limit,
            self.block_count,
            self.min_blocks,
            self.shards,
        );
        for input in &self.inputs {
            t += &format!("input={}\n", hex(input.to_string_lossy().as_bytes()));
        }
        for file in &self.files {
            t += &format!("file={file}\n");
        }
        if let Some(v) = self.nodata {
            t += &format!("nodata={}\n", float(v));
        }
        if let Some(a) = &self.assign {
            t += &format!(
                "assign={} {} {} {} {}\n",
                float(a.min_x),
                float(a.min_y),
                float(a.max_x),
                float(a.max_y),
                a.epsg
            );
        }
        t
    }

    /// Reads the file at `file`.
    pub(crate) fn read(file: &Path) -> Result<Self> {
        let text =
            std::fs::read_to_string(file).with_context(|| format!("reading {}", file.display()))?;
        Self::parse(&text).ok_or_else(|| {
            crate::BuildError::Invalid(format!(
                "{} is damaged or of another cbdam version: plan again in a new work directory",
                file.display()
            ))
        })
    }

    fn parse(text: &str) -> Option<Self> {
        let all = |name: &str| -> Vec<&str> {
            text.lines()
                .filter_map(|l| l.strip_prefix(name)?.strip_prefix('='))
                .collect()
        };
        let one = |name: &str| all(name).first().copied();
        let num = |name: &str| one(name)?.parse::<u64>().ok();
        let real = |s: &str| u64::from_str_radix(s, 16).ok().map(f64::from_bits);
        let path = |s: &str| Some(PathBuf::from(String::from_utf8(unhex(s)?).ok()?));
        let coder = one("coder")?;
        let assign = match one("assign") {
            None => None,
            Some(a) => {
                let p: Vec<&str> = a.split(' ').collect();
                let [x0, y0, x1, y1, epsg] = p[..] else {
                    return None;
                };
                Some(AssignedGeoRef {
                    min_x: real(x0)?,
                    min_y: real(y0)?,
                    max_x: real(x1)?,
                    max_y: real(y1)?,
                    epsg: epsg.parse().ok()?,
                })
            }
        };
        Some(Self {
            output: path(one("output")?)?,
            inputs: all("input").into_iter().map(path).collect::<Option<_>>()?,
            files: all("file").into_iter().map(str::to_string).collect(),
            nodata: match one("nodata") {
                None => None,
                Some(v) => Some(real(v)?),
            },
            assign,
            n: usize::try_from(num("n")?).ok()?,
            k: u32::try_from(num("k")?).ok()?,
            max_error: real(one("max_error")?)?,
            range: (real(one("low")?)?, real(one("high")?)?),
            coder: CoderKind::ALL
                .into_iter()
                .find(|c| format!("{c:?}") == coder)?,
            memory_limit: num("memory_limit")?,
            block_count: usize::try_from(num("blocks")?).ok()?,
            min_blocks: usize::try_from(num("min_blocks")?).ok()?,
            shards: usize::try_from(num("shards")?).ok()?.max(1),
        })
    }
}

/// The blocks of shard `shard` of `shards` over `count` blocks: runs of consecutive blocks.
pub(crate) fn share(count: usize, shards: usize, shard: usize) -> Range<usize> {
    let s = shards.max(1);
    shard * count / s..(shard + 1) * count / s
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every field reads back as written, floats to the bit; a file cut short does not read.
    #[test]
    fn the_planet_file_reads_back_exactly() {
        let plan = PlanetShardPlan {
            output: PathBuf::from("/w/out é.cbdam"),
            inputs: vec![PathBuf::from("/d/a.hgt"), PathBuf::from("@/d/list.txt")],
            files: vec!["2f642f612e686774 2884802 1700000000123456789".into()],
            nodata: Some(-32768.0),
            assign: Some(AssignedGeoRef {
                min_x: 0.1,
                min_y: -0.3,
                max_x: 1.0 / 3.0,
                max_y: 2.5,
                epsg: 4326,
            }),
            n: 17,
            k: 6,
            max_error: 0.1 + 0.2,
            range: (-10.25, 8848.86),
            coder: CoderKind::ALL[1],
            memory_limit: 96 << 20,
            block_count: 96,
            min_blocks: 8,
            shards: 3,
        };
        let text = plan.to_text();
        assert_eq!(PlanetShardPlan::parse(&text), Some(plan.clone()));
        let mut none = plan;
        none.nodata = None;
        none.assign = None;
        assert_eq!(PlanetShardPlan::parse(&none.to_text()), Some(none));
        let cut = &text[..text.find("coder").unwrap()];
        assert_eq!(PlanetShardPlan::parse(cut), None);
    }
}
