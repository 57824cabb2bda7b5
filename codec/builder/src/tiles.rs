//! Tile inputs: what `cbdam build INPUTS…` expands each input to before the mosaic
//! ([`crate::mosaic`]) places the files on one lattice.
//!
//! Each input is one of:
//! - a **file** (a DEM, as before);
//! - a **directory**: every DEM in it, by extension ([`DEM_EXTENSIONS`], case-insensitive),
//!   sorted by name, not recursive;
//! - a **glob**: `*`, `?` and `[…]` (ranges, `!` or `^` to negate) in the last path component,
//!   matching regular files, sorted; a path that exists as a file is taken literally;
//! - `@LIST`: one path a line, relative paths relative to the list file, blank lines and lines
//!   starting with `#` skipped; a listed directory or VRT is expanded like an argument;
//! - a **GDAL VRT** (`.vrt`) mosaic, in the subset `gdalbuildvrt` writes ([`read_vrt`]).
//!
//! Errors name the input: an empty directory, glob or list, a missing listed file, a list line
//! that is not a path, a VRT element or attribute outside the supported subset.

use std::path::{Component, Path, PathBuf};

use cbdam_codec::repository::GeoRef;

use crate::error::{Context, Result, bail};

/// The extensions a directory's DEMs are recognised by (case-insensitive).
pub const DEM_EXTENSIONS: &[&str] = &["tif", "tiff", "hgt", "asc", "png"];

/// One file of the mosaic, and what a VRT says about it.
#[derive(Clone, Debug, PartialEq)]
pub struct Tile {
    /// The DEM file.
    pub path: PathBuf,
    /// Where a VRT places the tile; `None` for a plain file.
    pub vrt: Option<VrtPlacement>,
}

/// A VRT source: where the VRT puts the tile, checked against the tile when it is read.
#[derive(Clone, Debug, PartialEq)]
pub struct VrtPlacement {
    /// The VRT file (for messages).
    pub vrt: PathBuf,
    /// The tile's size (`SrcRect` = `DstRect` size): it must be the whole tile.
    pub width: usize,
    /// Rows.
    pub height: usize,
    /// The tile's georeferencing from the VRT's `GeoTransform` and `DstRect` offset
    /// (PixelIsArea), with the EPSG code of its `SRS` where it names one.
    pub georef: GeoRef,
    /// The nodata value: the source's `NODATA`, else the band's `NoDataValue`.
    pub nodata: Option<f64>,
}

impl Tile {
    /// A plain file.
    pub fn file(path: impl Into<PathBuf>) -> Self {
        Tile {
            path: path.into(),
            vrt: None,
        }
    }
}

/// Expands every input (see the module documentation), in order.
pub fn expand_inputs(inputs: &[PathBuf]) -> Result<Vec<Tile>> {
    let mut out = Vec::new();
    for input in inputs {
        expand(input, true, &mut out)?;
    }
    Ok(out)
}

fn has_ext(path: &Path, exts: &[&str]) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| exts.iter().any(|x| e.eq_ignore_ascii_case(x)))
}

fn is_glob(text: &str) -> bool {
    text.contains(['*', '?', '['])
}

fn expand(input: &Path, lists: bool, out: &mut Vec<Tile>) -> Result<()> {
    let text = input.to_string_lossy();
    if lists && let Some(list) = text.strip_prefix('@') {
        return expand_list(Path::new(list), out);
    }
    if input.is_dir() {
        let mut found: Vec<PathBuf> = std::fs::read_dir(input)
            .with_context(|| format!("listing directory {}", input.display()))?
            .filter_map(|e| e.ok().map(|e| e.path()))
            .filter(|p| p.is_file() && has_ext(p, DEM_EXTENSIONS))
            .collect();
        if found.is_empty() {
            bail!(
                "directory {} holds no DEM (files ending .{})",
                input.display(),
                DEM_EXTENSIONS.join(", .")
            );
        }
        found.sort();
        out.extend(found.into_iter().map(Tile::file));
        return Ok(());
    }
    if !input.exists()
        && let Some(name) = input.file_name().map(|n| n.to_string_lossy())
        && is_glob(&name)
    {
        return expand_glob(input, &name, out);
    }
    if has_ext(input, &["vrt"]) {
        out.extend(read_vrt(input)?);
        return Ok(());
    }
    // A plain file; a missing one is named by the reader.
    check_regular_file(input, "input")?;
    out.push(Tile::file(input));
    Ok(())
}

/// Refuses a `role` (an input, a list, a VRT, a VRT's source…) that exists but is not a regular
/// file — a FIFO, a socket, a device — by its type, before opening it: reading a FIFO waits
/// for a writer, forever if none comes.
pub fn check_regular_file(path: &Path, role: &str) -> Result<()> {
    cbdam_codec::files::check_regular_file(path)
        .with_context(|| format!("{role} {}", path.display()))
}

fn expand_glob(input: &Path, pattern: &str, out: &mut Vec<Tile>) -> Result<()> {
    let dir = match input.parent() {
        Some(p) if !p.as_os_str().is_empty() => p,
        _ => Path::new("."),
    };
    if dir
        .components()
        .any(|c| matches!(c, Component::Normal(n) if is_glob(&n.to_string_lossy())))
    {
        bail!(
            "glob {}: wildcards are supported in the last path component only",
            input.display()
        );
    }
    let pattern: Vec<char> = pattern.chars().collect();
    let entries = std::fs::read_dir(dir)
        .with_context(|| format!("glob {}: listing {}", input.display(), dir.display()))?;
    let mut found = Vec::new();
    for e in entries {
        let e =
            e.with_context(|| format!("glob {}: listing {}", input.display(), dir.display()))?;
        let name: Vec<char> = e.file_name().to_string_lossy().chars().collect();
        // Like a shell, `*` does not match a leading dot.
        if name.first() == Some(&'.') && pattern.first() != Some(&'.') {
            continue;
        }
        if glob_match(&pattern, &name) && e.path().is_file() {
            found.push(input.with_file_name(e.file_name()));
        }
    }
    if found.is_empty() {
        bail!("glob {} matches no file", input.display());
    }
    found.sort();
    out.extend(found.into_iter().map(Tile::file));
    Ok(())
}

/// Whether `name` matches the glob `p`: `*` any run, `?` any one character, `[…]` a class.
pub fn glob_match(p: &[char], name: &[char]) -> bool {
    match p.first() {
        None => name.is_empty(),
        Some('*') => (0..=name.len()).any(|i| glob_match(&p[1..], &name[i..])),
        Some('?') => !name.is_empty() && glob_match(&p[1..], &name[1..]),
        Some('[') => {
            // An unclosed `[` is a literal.
            let Some(end) = p.iter().skip(2).position(|&c| c == ']').map(|i| i + 2) else {
                return name.first() == Some(&'[') && glob_match(&p[1..], &name[1..]);
            };
            let Some(&c) = name.first() else {
                return false;
            };
            let mut class = &p[1..end];
            let negate = matches!(class.first(), Some('!' | '^'));
            if negate {
                class = &class[1..];
            }
            let mut hit = false;
            let mut i = 0;
            while i < class.len() {
                if i + 2 < class.len() && class[i + 1] == '-' {
                    hit |= class[i] <= c && c <= class[i + 2];
                    i += 3;
                } else {
                    hit |= class[i] == c;
                    i += 1;
                }
            }
            hit != negate && glob_match(&p[end + 1..], &name[1..])
        }
        Some(&c) => name.first() == Some(&c) && glob_match(&p[1..], &name[1..]),
    }
}

fn expand_list(list: &Path, out: &mut Vec<Tile>) -> Result<()> {
    check_regular_file(list, "list")?;
    let text = std::fs::read_to_string(list)
        .with_context(|| format!("reading list @{}", list.display()))?;
    let base = list.parent().unwrap_or(Path::new(""));
    let before = out.len();
    for (n, line) in text.lines().enumerate() {
        let line = line.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        if line.chars().any(char::is_control) {
            bail!(
                "line {} of list @{} is not a path (it holds a control character): {line:?}",
                n + 1,
                list.display()
            );
        }
        let path = base.join(line);
        if !path.exists() {
            bail!(
                "line {} of list @{}: {} does not exist",
                n + 1,
                list.display(),
                path.display()
            );
        }
        expand(&path, false, out)?;
    }
    if out.len() == before {
        bail!("list @{} names no file", list.display());
    }
    Ok(())
}

/// The attributes and child elements the supported VRT subset allows in each element.
fn allowed(element: &str) -> Option<(&'static [&'static str], &'static [&'static str])> {
    Some(match element {
        "VRTDataset" => (
            &["rasterXSize", "rasterYSize"],
            &["SRS", "GeoTransform", "VRTRasterBand"],
        ),
        "SRS" => (&["dataAxisToSRSAxisMapping"], &[]),
        "GeoTransform" | "NoDataValue" | "ColorInterp" | "SourceBand" | "NODATA" => (&[], &[]),
        "VRTRasterBand" => (
            &["dataType", "band"],
            &[
                "NoDataValue",
                "ColorInterp",
                "SimpleSource",
                "ComplexSource",
            ],
        ),
        "SimpleSource" => (
            &[],
            &[
                "SourceFilename",
                "SourceBand",
                "SourceProperties",
                "SrcRect",
                "DstRect",
            ],
        ),
        "ComplexSource" => (
            &[],
            &[
                "SourceFilename",
                "SourceBand",
                "SourceProperties",
                "SrcRect",
                "DstRect",
                "NODATA",
            ],
        ),
        "SourceFilename" => (&["relativeToVRT", "relativetoVRT", "shared"], &[]),
        "SourceProperties" => (
            &[
                "RasterXSize",
                "RasterYSize",
                "DataType",
                "BlockXSize",
                "BlockYSize",
            ],
            &[],
        ),
        "SrcRect" | "DstRect" => (&["xOff", "yOff", "xSize", "ySize"], &[]),
        _ => return None,
    })
}

/// Refuses anything in `node`'s subtree outside the supported subset, naming it.
fn check_subset(vrt: &Path, node: roxmltree::Node<'_, '_>) -> Result<()> {
    let name = node.tag_name().name();
    let Some((attrs, children)) = allowed(name) else {
        bail!(
            "{}: element <{name}> is not supported (only untransformed SimpleSource/\
             ComplexSource tiles of one band, as gdalbuildvrt writes them, are)",
            vrt.display()
        );
    };
    for a in node.attributes() {
        if !attrs.contains(&a.name()) {
            bail!(
                "{}: attribute {}=\"{}\" of <{name}> is not supported",
                vrt.display(),
                a.name(),
                a.value()
            );
        }
    }
    for c in node.children().filter(|c| c.is_element()) {
        let cn = c.tag_name().name();
        if !children.contains(&cn) {
            bail!(
                "{}: element <{cn}> in <{name}> is not supported (only untransformed \
                 SimpleSource/ComplexSource tiles of one band, as gdalbuildvrt writes them, are)",
                vrt.display()
            );
        }
        check_subset(vrt, c)?;
    }
    Ok(())
}

fn child<'a, 'i>(node: roxmltree::Node<'a, 'i>, name: &str) -> Option<roxmltree::Node<'a, 'i>> {
    node.children().find(|c| c.tag_name().name() == name)
}

fn number<T: std::str::FromStr>(vrt: &Path, what: &str, text: Option<&str>) -> Result<T> {
    let Some(text) = text else {
        bail!("{}: {what} is missing", vrt.display());
    };
    match text.trim().parse() {
        Ok(v) => Ok(v),
        Err(_) => bail!("{}: {what} {text:?} is not a valid number", vrt.display()),
    }
}

/// A rectangle `(xOff, yOff, xSize, ySize)` of whole pixels.
fn rect(vrt: &Path, src: roxmltree::Node<'_, '_>, name: &str) -> Result<[usize; 4]> {
    let Some(r) = child(src, name) else {
        bail!("{}: a source has no <{name}>", vrt.display());
    };
    let mut v = [0usize; 4];
    for (i, a) in ["xOff", "yOff", "xSize", "ySize"].iter().enumerate() {
        let x: f64 = number(vrt, &format!("<{name}> {a}"), r.attribute(*a))?;
        if !(x >= 0.0 && x.fract() == 0.0) {
            bail!(
                "{}: <{name}> {a}=\"{x}\" is not a whole number of pixels (sub-pixel placement \
                 would need resampling)",
                vrt.display()
            );
        }
        v[i] = x as usize;
    }
    Ok(v)
}

/// The EPSG code an SRS names: `EPSG:n`, or the last `AUTHORITY["EPSG","n"]` / `ID["EPSG",n]`
/// of a WKT (the root's).
fn srs_epsg(srs: &str) -> Option<u32> {
    let s = srs.trim();
    if let Some(n) = s.strip_prefix("EPSG:") {
        return n.trim().parse().ok();
    }
    let at = s.rfind("\"EPSG\"")?;
    let rest = &s[at + 6..];
    let digits: String = rest
        .trim_start_matches([',', ' ', '"'])
        .chars()
        .take_while(char::is_ascii_digit)
        .collect();
    digits.parse().ok()
}

/// Reads a GDAL VRT mosaic: the tiles it places and where. The subset supported is what
/// `gdalbuildvrt` writes: a `VRTDataset` with `rasterXSize`/`rasterYSize`, a north-up
/// `GeoTransform`, an optional `SRS`, one `VRTRasterBand` (`dataType`, optional `NoDataValue`,
/// `ColorInterp`) of `SimpleSource`/`ComplexSource` elements (`SourceFilename`, `SourceBand` 1,
/// `SourceProperties`, `SrcRect`, `DstRect`, and for a `ComplexSource` an optional `NODATA`),
/// each a whole tile placed without scaling. Anything else is refused, naming the element or
/// attribute; the tiles' own sizes and georeferencing are checked when the mosaic reads them.
pub fn read_vrt(vrt: &Path) -> Result<Vec<Tile>> {
    check_regular_file(vrt, "VRT")?;
    let text =
        std::fs::read_to_string(vrt).with_context(|| format!("reading {}", vrt.display()))?;
    let doc = roxmltree::Document::parse(&text)
        .with_context(|| format!("reading {} (XML)", vrt.display()))?;
    let root = doc.root_element();
    if root.tag_name().name() != "VRTDataset" {
        bail!(
            "{}: the root element is <{}>, not <VRTDataset>",
            vrt.display(),
            root.tag_name().name()
        );
    }
    check_subset(vrt, root)?;
    let raster = VrtRaster {
        vrt,
        width: number(vrt, "rasterXSize", root.attribute("rasterXSize"))?,
        height: number(vrt, "rasterYSize", root.attribute("rasterYSize"))?,
        geo_transform: parse_geo_transform(vrt, root)?,
        epsg: child(root, "SRS").and_then(|s| s.text()).and_then(srs_epsg),
    };
    let (band, band_nodata) = parse_band(vrt, root)?;
    let base = vrt.parent().unwrap_or(Path::new(""));
    let tiles = band
        .children()
        .filter(|c| matches!(c.tag_name().name(), "SimpleSource" | "ComplexSource"))
        .map(|src| raster.parse_source(src, base, band_nodata))
        .collect::<Result<Vec<_>>>()?;
    if tiles.is_empty() {
        bail!(
            "{}: no <SimpleSource> or <ComplexSource>: the VRT places no tile",
            vrt.display()
        );
    }
    Ok(tiles)
}

/// The VRT's raster, which its sources are placed on.
struct VrtRaster<'a> {
    vrt: &'a Path,
    width: usize,
    height: usize,
    /// GDAL's six terms, checked north-up.
    geo_transform: [f64; 6],
    epsg: Option<u32>,
}

/// The `<GeoTransform>`: six finite terms of a north-up grid.
fn parse_geo_transform(vrt: &Path, root: roxmltree::Node<'_, '_>) -> Result<[f64; 6]> {
    let Some(gt) = child(root, "GeoTransform") else {
        bail!(
            "{}: no <GeoTransform>: the tiles cannot be placed",
            vrt.display()
        );
    };
    let gt: Vec<f64> = gt
        .text()
        .unwrap_or("")
        .split(',')
        .map(|t| number(vrt, "a <GeoTransform> term", Some(t)))
        .collect::<Result<_>>()?;
    let Ok(gt) = <[f64; 6]>::try_from(gt.as_slice()) else {
        bail!(
            "{}: <GeoTransform> has {} terms, not 6",
            vrt.display(),
            gt.len()
        );
    };
    if let Some(t) = gt.iter().find(|t| !t.is_finite()) {
        bail!(
            "{}: <GeoTransform> {gt:?} holds {t}: every term must be a finite number",
            vrt.display()
        );
    }
    if gt[2] != 0.0 || gt[4] != 0.0 || !(gt[1] > 0.0 && gt[5] < 0.0) {
        bail!(
            "{}: <GeoTransform> {gt:?} is not north-up (rotation terms 0, positive x and \
             negative y spacing): only north-up grids are combined",
            vrt.display()
        );
    }
    Ok(gt)
}

/// The one `<VRTRasterBand>` (band 1, a supported `dataType`) and its `<NoDataValue>`.
fn parse_band<'a, 'i>(
    vrt: &Path,
    root: roxmltree::Node<'a, 'i>,
) -> Result<(roxmltree::Node<'a, 'i>, Option<f64>)> {
    let bands: Vec<_> = root
        .children()
        .filter(|c| c.tag_name().name() == "VRTRasterBand")
        .collect();
    let band = match bands.as_slice() {
        [b] => *b,
        [] => bail!("{}: no <VRTRasterBand>", vrt.display()),
        _ => bail!(
            "{}: a second <VRTRasterBand>: elevation mosaics have one band",
            vrt.display()
        ),
    };
    if let Some(b) = band.attribute("band")
        && b.trim() != "1"
    {
        bail!(
            "{}: <VRTRasterBand band=\"{b}\">: only band 1",
            vrt.display()
        );
    }
    const TYPES: &[&str] = &[
        "Byte", "Int8", "UInt16", "Int16", "UInt32", "Int32", "Float32", "Float64",
    ];
    if let Some(t) = band.attribute("dataType")
        && !TYPES.contains(&t)
    {
        bail!(
            "{}: <VRTRasterBand dataType=\"{t}\"> is not supported (one of {})",
            vrt.display(),
            TYPES.join(", ")
        );
    }
    let nodata = parse_nodata(vrt, child(band, "NoDataValue"), "<NoDataValue>")?;
    Ok((band, nodata))
}

/// A nodata element's value: a number or `nan`.
fn parse_nodata(
    vrt: &Path,
    node: Option<roxmltree::Node<'_, '_>>,
    what: &str,
) -> Result<Option<f64>> {
    match node.and_then(|n| n.text()) {
        None => Ok(None),
        Some(t) if t.trim().eq_ignore_ascii_case("nan") => Ok(Some(f64::NAN)),
        Some(t) => number(vrt, what, Some(t)).map(Some),
    }
}

impl VrtRaster<'_> {
    /// One `<SimpleSource>`/`<ComplexSource>`: a whole tile placed on the raster unscaled.
    fn parse_source(
        &self,
        src: roxmltree::Node<'_, '_>,
        base: &Path,
        band_nodata: Option<f64>,
    ) -> Result<Tile> {
        let vrt = self.vrt;
        let (name, path) = source_path(vrt, src, base)?;
        let sb: u32 = number(
            vrt,
            &format!("<SourceBand> of {name}"),
            child(src, "SourceBand")
                .and_then(|b| b.text())
                .or(Some("1")),
        )?;
        if sb != 1 {
            bail!(
                "{}: <SourceBand>{sb}</SourceBand> of {name}: only band 1 of a tile",
                vrt.display()
            );
        }
        let (size, dst) = self.placement(src, &name)?;
        let nodata = match parse_nodata(vrt, child(src, "NODATA"), &format!("<NODATA> of {name}"))?
        {
            Some(v) => Some(v),
            None => band_nodata,
        };
        let gt = &self.geo_transform;
        Ok(Tile {
            path,
            vrt: Some(VrtPlacement {
                vrt: vrt.to_path_buf(),
                width: size[0],
                height: size[1],
                georef: GeoRef {
                    origin_x: gt[0] + dst[0] as f64 * gt[1],
                    origin_y: gt[3] + dst[1] as f64 * gt[5],
                    pixel_x: gt[1],
                    pixel_y: -gt[5],
                    pixel_is_area: true,
                    epsg: self.epsg,
                    wkt: None,
                },
                nodata,
            }),
        })
    }

    /// A source's size and its offset on the raster, from `<SrcRect>` (the whole tile) and
    /// `<DstRect>` (the same size, inside the raster).
    fn placement(
        &self,
        src: roxmltree::Node<'_, '_>,
        name: &str,
    ) -> Result<([usize; 2], [usize; 2])> {
        let vrt = self.vrt;
        let (xsize, ysize) = (self.width, self.height);
        let s = rect(vrt, src, "SrcRect")?;
        let d = rect(vrt, src, "DstRect")?;
        if s[0] != 0 || s[1] != 0 {
            bail!(
                "{}: <SrcRect> of {name} starts at ({}, {}): only whole tiles are supported \
                 (SrcRect at 0, 0 covering the tile)",
                vrt.display(),
                s[0],
                s[1]
            );
        }
        if s[2] != d[2] || s[3] != d[3] {
            bail!(
                "{}: <SrcRect> {}×{} and <DstRect> {}×{} of {name} differ: scaling would need \
                 resampling",
                vrt.display(),
                s[2],
                s[3],
                d[2],
                d[3]
            );
        }
        if s[2] == 0 || s[3] == 0 || d[0] + d[2] > xsize || d[1] + d[3] > ysize {
            bail!(
                "{}: <DstRect> of {name} ({}, {}, {}×{}) is empty or outside the \
                 {xsize}×{ysize} raster",
                vrt.display(),
                d[0],
                d[1],
                d[2],
                d[3]
            );
        }
        Ok(([s[2], s[3]], [d[0], d[1]]))
    }
}

/// A source's `<SourceFilename>` as written and as a path (relative to the VRT's folder when
/// `relativeToVRT="1"`), checked to be a regular file.
fn source_path(vrt: &Path, src: roxmltree::Node<'_, '_>, base: &Path) -> Result<(String, PathBuf)> {
    let kind = src.tag_name().name();
    let Some(file) = child(src, "SourceFilename") else {
        bail!("{}: a <{kind}> has no <SourceFilename>", vrt.display());
    };
    let name = file.text().unwrap_or("").trim();
    if name.is_empty() {
        bail!("{}: an empty <SourceFilename>", vrt.display());
    }
    if name.starts_with("/vsi") {
        bail!(
            "{}: <SourceFilename> {name}: GDAL virtual file systems are not supported",
            vrt.display()
        );
    }
    let relative = file
        .attribute("relativeToVRT")
        .or(file.attribute("relativetoVRT"))
        .is_some_and(|v| v.trim() == "1");
    let path = if relative {
        base.join(name)
    } else {
        PathBuf::from(name)
    };
    check_regular_file(&path, &format!("{}: source", vrt.display()))?;
    Ok((name.to_string(), path))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn globs_match_like_a_shell() {
        let m = |p: &str, n: &str| {
            glob_match(
                &p.chars().collect::<Vec<_>>(),
                &n.chars().collect::<Vec<_>>(),
            )
        };
        assert!(m("*.hgt", "N45E006.hgt"));
        assert!(!m("*.hgt", "N45E006.tif"));
        assert!(m("N4?E00[6-7].hgt", "N45E007.hgt"));
        assert!(!m("N4?E00[6-7].hgt", "N45E008.hgt"));
        assert!(m("N4?E00[!6].hgt", "N45E008.hgt"));
        assert!(!m("N4?E00[^8].hgt", "N45E008.hgt"));
        assert!(m("a[b", "a[b"));
        assert!(m("*", ""));
        assert!(!m("?", ""));
    }

    #[test]
    fn srs_epsg_codes() {
        assert_eq!(srs_epsg("EPSG:4326"), Some(4326));
        assert_eq!(
            srs_epsg(
                r#"GEOGCS["WGS 84",DATUM["WGS_1984",SPHEROID["WGS 84",6378137,298.257223563,AUTHORITY["EPSG","7030"]],AUTHORITY["EPSG","6326"]],PRIMEM["Greenwich",0],UNIT["degree",0.0174532925199433],AUTHORITY["EPSG","4326"]]"#
            ),
            Some(4326)
        );
        assert_eq!(srs_epsg("LOCAL_CS[\"x\"]"), None);
    }
}
