//! What several subcommands share on the command line: typed values parsed once by clap — sizes
//! `WIDTHxHEIGHT` ([`Size2`]), byte counts ([`ByteSize`]), link rates ([`BitRate`]), geodetic
//! cameras ([`GeoView`]), numbers that must be positive ([`positive_finite`]) or not negative
//! ([`non_negative_finite`]) — and the flags
//! defined once and flattened into each command that takes them ([`PixelError`], [`BudgetMs`],
//! [`Fps`], [`Colour`], [`PoolMib`], [`Look`], [`DiamondSize`], [`Quiet`], [`GeorefArgs`]). A command
//! whose help says more about one of them (`render --fps` only with `--path`) adds it with
//! `mut_arg` on its own arguments.
//!
//! A bad value is a usage error (exit 2) whose message names the flag (clap puts it in front)
//! and says what is expected.

use clap::Args;

/// The largest image or window side accepted (`--size` of render, view, replay, bench render):
/// what GPUs allow for a texture.
pub const MAX_PIXELS: u64 = 16384;

/// `WIDTHxHEIGHT`: two whole numbers from 1 to a bound, separated by `x`, `X` or `×`, with
/// optional spaces around each number.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Size2 {
    /// The first number.
    pub width: u64,
    /// The second number.
    pub height: u64,
}

impl Size2 {
    /// Parses `text` with both numbers from 1 to `max`.
    pub fn parse(text: &str, max: u64) -> Result<Size2, String> {
        let bad = || {
            if max == u64::MAX {
                format!(
                    "{text:?} is not WIDTHxHEIGHT of two whole numbers from 1 (e.g. 16385x16385)"
                )
            } else {
                format!(
                    "{text:?} is not WIDTHxHEIGHT of two whole numbers from 1 to {max} \
                     (e.g. 1920x1080)"
                )
            }
        };
        let (w, h) = text.split_once(['x', 'X', '×']).ok_or_else(bad)?;
        let side = |t: &str| {
            t.trim()
                .parse::<u64>()
                .ok()
                .filter(|v| (1..=max).contains(v))
                .ok_or_else(bad)
        };
        Ok(Size2 {
            width: side(w)?,
            height: side(h)?,
        })
    }

    /// clap parser of an image or window size in pixels, each side 1 to [`MAX_PIXELS`].
    pub fn pixels(text: &str) -> Result<(u32, u32), String> {
        let s = Size2::parse(text, MAX_PIXELS)?;
        // Both fit: MAX_PIXELS < u32::MAX.
        Ok((s.width as u32, s.height as u32))
    }

    /// clap parser of a grid size in samples (`cbdam build --size`), each side at least 1.
    pub fn samples(text: &str) -> Result<(usize, usize), String> {
        let s = Size2::parse(text, usize::MAX as u64)?;
        Ok((s.width as usize, s.height as usize))
    }
}

/// Splits `text` into a finite decimal number and the unit after it (trimmed, lower case), as
/// [`ByteSize`] and [`BitRate`] write them; `None` when the number does not parse.
fn number_and_unit(text: &str) -> Option<(f64, String)> {
    let t = text.trim();
    let digits = t
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .unwrap_or(t.len());
    let (num, unit) = t.split_at(digits);
    let value: f64 = num.parse().ok().filter(|v: &f64| v.is_finite())?;
    Some((value, unit.trim().to_ascii_lowercase()))
}

/// A number of bytes: a number with an optional binary suffix K, M, G or T (also KiB, KB …, any
/// case), e.g. `2G`, `512M`, `1.5G`, `1073741824`; at least one byte and below 16 EiB.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ByteSize(pub u64);

impl std::str::FromStr for ByteSize {
    type Err = String;

    fn from_str(text: &str) -> Result<ByteSize, String> {
        let bad = || {
            format!(
                "{text:?} is not a size: a number of bytes from 1 to below 16 EiB, with K, M, G \
                 or T for powers of 1024 (e.g. 2G or 512M)"
            )
        };
        let (value, suffix) = number_and_unit(text).ok_or_else(bad)?;
        let scale: u64 = match suffix.as_str() {
            "" | "b" => 1,
            "k" | "kb" | "kib" => 1 << 10,
            "m" | "mb" | "mib" => 1 << 20,
            "g" | "gb" | "gib" => 1 << 30,
            "t" | "tb" | "tib" => 1 << 40,
            _ => return Err(bad()),
        };
        let bytes = value * scale as f64;
        if bytes < 1.0 || bytes >= u64::MAX as f64 {
            return Err(bad());
        }
        Ok(ByteSize(bytes as u64))
    }
}

/// A rate in bits per second: a number with an optional decimal suffix k, M or G (powers of 1000,
/// any case, optionally followed by `bit/s`, `bps` or `b`), e.g. `1.2M`, `256k`, `10Mbit/s`,
/// `5000000`; from 1000 bit/s (1k) to 1000 Gbit/s.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct BitRate(pub u64);

impl std::str::FromStr for BitRate {
    type Err = String;

    fn from_str(text: &str) -> Result<BitRate, String> {
        let bad = || {
            format!(
                "{text:?} is not a rate: bits per second from 1k to 1000G, with k, M or G for \
                 powers of 1000 (e.g. 1.2M or 256k)"
            )
        };
        let (value, suffix) = number_and_unit(text).ok_or_else(bad)?;
        let unit = ["bit/s", "bps", "b"]
            .iter()
            .find_map(|u| suffix.strip_suffix(u))
            .unwrap_or(&suffix);
        let scale: f64 = match unit.trim() {
            "" => 1.0,
            "k" => 1e3,
            "m" => 1e6,
            "g" => 1e9,
            _ => return Err(bad()),
        };
        let bps = (value * scale).round();
        if !(1e3..=1e12).contains(&bps) {
            return Err(bad());
        }
        Ok(BitRate(bps as u64))
    }
}

/// `LAT,LON,HEIGHT_M[,HEADING_DEG,PITCH_DEG]`: a geodetic camera (`render --geo`): latitude
/// and longitude in degrees, height in metres above the WGS84 ellipsoid, heading clockwise from
/// north (default 0), pitch negative looking down (default −30).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GeoView {
    /// Degrees north, −90 to 90.
    pub lat: f64,
    /// Degrees east.
    pub lon: f64,
    /// Metres above the ellipsoid.
    pub height: f64,
    /// Degrees clockwise from north.
    pub heading: f64,
    /// Degrees above the horizon (negative: looking down), −90 to 90.
    pub pitch: f64,
}

impl GeoView {
    /// Parses `LAT,LON,HEIGHT_M[,HEADING_DEG,PITCH_DEG]`.
    pub fn parse(text: &str) -> Result<GeoView, String> {
        let v: Vec<f64> = text
            .split(',')
            .map(|t| t.trim().parse::<f64>())
            .collect::<Result<_, _>>()
            .map_err(|_| {
                format!("{text:?} is not LAT,LON,HEIGHT_M[,HEADING_DEG,PITCH_DEG] of numbers")
            })?;
        if !(v.len() == 3 || v.len() == 5) {
            return Err(format!(
                "{text:?}: wants 3 or 5 numbers LAT,LON,HEIGHT_M[,HEADING_DEG,PITCH_DEG], got {}",
                v.len()
            ));
        }
        if v.iter().any(|x| !x.is_finite()) {
            return Err(format!("{text:?}: every number must be finite"));
        }
        let (heading, pitch) = if v.len() == 5 {
            (v[3], v[4])
        } else {
            (0.0, -30.0)
        };
        if !(-90.0..=90.0).contains(&v[0]) {
            return Err(format!("{text:?}: latitude {} is not within −90…90", v[0]));
        }
        if !(-90.0..=90.0).contains(&pitch) {
            return Err(format!("{text:?}: pitch {pitch} is not within −90…90"));
        }
        if v[2] <= -1.0e5 {
            return Err(format!(
                "{text:?}: height {} m is deep inside the Earth (metres above the ellipsoid)",
                v[2]
            ));
        }
        Ok(GeoView {
            lat: v[0],
            lon: v[1],
            height: v[2],
            heading,
            pitch,
        })
    }
}

/// clap parser of a number that must be positive and finite (`--fps`, `--pixel-error`,
/// `--timeout` …); clap names the flag in front of the message.
pub fn positive_finite(text: &str) -> Result<f64, String> {
    let value: f64 = text
        .parse()
        .map_err(|e: std::num::ParseFloatError| e.to_string())?;
    if value.is_finite() && value > 0.0 {
        Ok(value)
    } else {
        Err("must be a positive finite number".into())
    }
}

/// clap parser of a number that must be 0 or positive and finite (`--budget-ms`, where 0 means
/// unlimited; `--interval` …); clap names the flag in front of the message.
pub fn non_negative_finite(text: &str) -> Result<f64, String> {
    let value: f64 = text
        .parse()
        .map_err(|e: std::num::ParseFloatError| e.to_string())?;
    if value.is_finite() && value >= 0.0 {
        Ok(value)
    } else {
        Err("must be 0 or a positive finite number".into())
    }
}

/// `--pixel-error`: the screen-space error target of the refinement loop.
#[derive(Args, Clone, Copy, Debug)]
pub struct PixelError {
    /// Screen-space error target, pixels.
    #[arg(
        id = "pixel_error",
        long = "pixel-error",
        value_name = "PIXEL_ERROR",
        default_value_t = 1.0,
        value_parser = positive_finite,
        allow_hyphen_values = true
    )]
    pub value: f64,
}

/// `--budget-ms`: the refinement loop's time per frame, 0 for unlimited. `view`, which refines
/// within a budget every frame, has its own.
#[derive(Args, Clone, Copy, Debug)]
pub struct BudgetMs {
    /// Refinement time budget per frame, ms (0: unlimited).
    #[arg(
        id = "budget_ms",
        long = "budget-ms",
        value_name = "BUDGET_MS",
        default_value_t = 2.0,
        value_parser = non_negative_finite,
        allow_hyphen_values = true
    )]
    pub value: f64,
}

/// `--fps`: frames per second of a camera flight.
#[derive(Args, Clone, Copy, Debug)]
pub struct Fps {
    /// Frames per second of flight time.
    #[arg(
        id = "fps",
        long = "fps",
        value_name = "FPS",
        default_value_t = 30.0,
        value_parser = positive_finite,
        allow_hyphen_values = true
    )]
    pub value: f64,
}

/// `--colour`: a colour repository, file or URL, draped over the terrain.
#[derive(Args, Clone, Debug)]
pub struct Colour {
    /// Drape this colour repository (`cbdam build IMG --colour --like REPO`), file or URL, over
    /// the terrain: hillshaded colour instead of the height ramp.
    #[arg(id = "colour", long = "colour", value_name = "COLOUR_REPO_OR_URL")]
    pub value: Option<String>,
}

/// `--pool-mib`: the renderer's GPU height pool.
#[derive(Args, Clone, Copy, Debug)]
pub struct PoolMib {
    /// GPU height pool, MiB (default: 256 or what the adapter allows).
    #[arg(id = "pool_mib", long = "pool-mib", value_name = "POOL_MIB")]
    pub value: Option<u64>,
}

/// How the surface is drawn (`render`, `view`): `--wireframe`, `--levels`, `--exaggeration`.
#[derive(Args, Clone, Copy, Debug)]
pub struct Look {
    /// Draw triangle edges over the surface (`view`: Tab or 1 toggles it).
    #[arg(long)]
    pub wireframe: bool,
    /// Colour by diamond level instead of height (`view`: L toggles it).
    #[arg(long)]
    pub levels: bool,
    /// Vertical exaggeration (heights and the camera's z are scaled by it).
    #[arg(long, default_value_t = 1.0, value_parser = positive_finite, allow_hyphen_values = true)]
    pub exaggeration: f64,
}

/// `--diamond-size`: the side of a diamond's grid.
#[derive(Args, Clone, Copy, Debug)]
pub struct DiamondSize {
    /// Diamond grid side N (2^k + 1).
    #[arg(
        id = "diamond_size",
        long = "diamond-size",
        value_name = "DIAMOND_SIZE",
        default_value_t = 65
    )]
    pub value: usize,
}

/// `--quiet`: nothing printed on success.
#[derive(Args, Clone, Copy, Debug)]
pub struct Quiet {
    /// Print nothing on success.
    #[arg(id = "quiet", long = "quiet")]
    pub value: bool,
}

/// `--bounds MINX,MINY,MAXX,MAXY --crs EPSG:N`, of `build` and `verify`: georeferencing for an
/// input that carries none.
#[derive(Args, Debug, Default)]
pub struct GeorefArgs {
    /// Georeferences an input that carries none (a raw float32 file, a plain TIFF, one of a
    /// planet's inputs): the outer edges of its raster in the CRS of --crs,
    /// west,south,east,north (GDAL's -te order), e.g. `--bounds -10,40,2,46 --crs EPSG:4326`.
    /// Refused for inputs with their own; among a planet's inputs, for the one that carries
    /// none (`verify --against` takes the same flags to place it again).
    #[arg(
        long,
        value_name = "MINX,MINY,MAXX,MAXY",
        requires = "crs",
        allow_hyphen_values = true
    )]
    bounds: Option<String>,
    /// The CRS of --bounds, as EPSG:N.
    #[arg(long, value_name = "EPSG:N", requires = "bounds")]
    crs: Option<String>,
}

impl GeorefArgs {
    /// The georeferencing the flags give, checked; `None` without them.
    pub fn assigned(&self) -> anyhow::Result<Option<cbdam_builder::assign::AssignedGeoRef>> {
        match (&self.bounds, &self.crs) {
            (Some(b), Some(c)) => Ok(Some(cbdam_builder::assign::AssignedGeoRef::parse(b, c)?)),
            _ => Ok(None),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn positive_finite_numbers_pass_and_the_rest_is_refused_with_the_reason() {
        assert_eq!(positive_finite("30"), Ok(30.0));
        assert_eq!(positive_finite("0.25"), Ok(0.25));
        assert_eq!(positive_finite("1e-3"), Ok(0.001));
        for bad in ["0", "-0", "-1", "NaN", "inf", "-inf"] {
            assert_eq!(
                positive_finite(bad),
                Err("must be a positive finite number".into()),
                "{bad}"
            );
        }
        // Not a number at all: the standard library's reason, as clap's own f64 parser gives.
        assert_eq!(positive_finite("abc"), Err("invalid float literal".into()));
        assert!(positive_finite("").is_err());
    }

    #[test]
    fn non_negative_finite_numbers_pass_with_zero_and_the_rest_is_refused() {
        assert_eq!(non_negative_finite("0"), Ok(0.0));
        assert_eq!(non_negative_finite("2"), Ok(2.0));
        for bad in ["-1", "-1e-9", "NaN", "inf"] {
            assert_eq!(
                non_negative_finite(bad),
                Err("must be 0 or a positive finite number".into()),
                "{bad}"
            );
        }
        assert_eq!(
            non_negative_finite("x"),
            Err("invalid float literal".into())
        );
    }

    #[test]
    fn geo_views_parse_with_defaults_and_refuse_nonsense() {
        let g = GeoView::parse("45.5, -122.25,1500").unwrap();
        assert_eq!(
            (g.lat, g.lon, g.height, g.heading, g.pitch),
            (45.5, -122.25, 1500.0, 0.0, -30.0)
        );
        let g = GeoView::parse("0,180,1,90,-10").unwrap();
        assert_eq!((g.heading, g.pitch), (90.0, -10.0));
        for bad in [
            "1,2",
            "1,2,3,4",
            "91,0,10",
            "0,0,10,0,-91",
            "a,b,c",
            "0,0,inf",
            "0,0,-200000",
        ] {
            assert!(GeoView::parse(bad).is_err(), "{bad}");
        }
    }

    #[test]
    fn sizes_accept_every_separator_and_refuse_junk() {
        assert_eq!(Size2::pixels("1920x1080"), Ok((1920, 1080)));
        assert_eq!(Size2::pixels("3X2"), Ok((3, 2)));
        assert_eq!(Size2::pixels("64×48"), Ok((64, 48)));
        assert_eq!(Size2::pixels(" 96 x 64 "), Ok((96, 64)));
        assert_eq!(Size2::pixels("16384x1"), Ok((16384, 1)));
        assert_eq!(Size2::samples("16385x16385"), Ok((16385, 16385)));
        assert_eq!(Size2::samples("131×77"), Ok((131, 77)));
        // Lattices are not bounded by what a GPU allows.
        assert_eq!(Size2::samples("100000x3"), Ok((100000, 3)));
        for bad in [
            "16385", "0x5", "5x0", "5x", "x5", "ax3", "-1x3", "1.5x2", "2x3x4", "",
        ] {
            assert!(Size2::pixels(bad).is_err(), "{bad:?} accepted");
            assert!(Size2::samples(bad).is_err(), "{bad:?} accepted");
        }
        assert!(Size2::pixels("16385x16").is_err());
        assert!(Size2::pixels("16x99999999999").is_err());
        // One message: the input, the form, the range.
        let e = Size2::pixels("0x5").unwrap_err();
        assert!(
            e.contains("\"0x5\"") && e.contains("WIDTHxHEIGHT") && e.contains("16384"),
            "{e}"
        );
        let e = Size2::samples("131").unwrap_err();
        assert!(e.contains("\"131\"") && e.contains("WIDTHxHEIGHT"), "{e}");
    }

    #[test]
    fn byte_sizes_parse_with_binary_suffixes_and_junk_is_refused() {
        let b = |t: &str| t.parse::<ByteSize>().map(|b| b.0);
        assert_eq!(b("2G"), Ok(2 << 30));
        assert_eq!(b("512m"), Ok(512 << 20));
        assert_eq!(b("1.5GiB"), Ok(3 << 29));
        assert_eq!(b("4096"), Ok(4096));
        assert_eq!(b(" 64 K "), Ok(64 << 10));
        assert_eq!(b("4K"), Ok(4096));
        assert_eq!(b("1M"), Ok(1 << 20));
        for bad in [
            "",
            "G",
            "-1G",
            "0",
            "0.1",
            "2X",
            "1e3",
            "nanG",
            "1..2G",
            "99999999999T",
            "lots",
        ] {
            assert!(b(bad).is_err(), "{bad:?} accepted");
        }
        let e = b("lots").unwrap_err();
        assert!(e.contains("\"lots\"") && e.contains("2G"), "{e}");
    }

    #[test]
    fn bit_rates_parse_with_decimal_suffixes_and_junk_is_refused() {
        let r = |t: &str| t.parse::<BitRate>().map(|b| b.0);
        assert_eq!(r("1.2M"), Ok(1_200_000));
        assert_eq!(r("256k"), Ok(256_000));
        assert_eq!(r("10Mbit/s"), Ok(10_000_000));
        assert_eq!(r(" 100 mbps "), Ok(100_000_000));
        assert_eq!(r("1G"), Ok(1_000_000_000));
        assert_eq!(r("5000000"), Ok(5_000_000));
        assert_eq!(r("1kb"), Ok(1000));
        for bad in [
            "", "M", "-1M", "999", "0.5k", "2X", "1e6", "1001G", "1..2M", "fast",
        ] {
            assert!(r(bad).is_err(), "{bad:?} accepted");
        }
        let e = r("fast").unwrap_err();
        assert!(e.contains("\"fast\"") && e.contains("1.2M"), "{e}");
    }
}
