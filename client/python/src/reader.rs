//! `cbdam.Reader`: an open repository, local or remote — its header as Python values, and
//! `read` (one even level over a window, as a NumPy array written in place without the GIL) and
//! `sample` (heights at points, bilinear between the finest level's samples).

use std::path::PathBuf;
use std::time::Duration;

use cbdam_codec::geometry::DomainKind;
use cbdam_codec::repository::{GeoRef, LevelGrid, bbox_window};
use numpy::{PyArray1, PyArray2, PyArrayMethods, PyReadonlyArray1};
use pyo3::prelude::*;
use pyo3::types::{PyAny, PyDict};

use crate::errors::{PyCbdamError, Result};
use crate::planet::{self, GeoGrid};
use crate::source::{Sample, Source};

/// A window `(col_off, row_off, width, height)` of the input grid: a tuple, or anything with
/// those four attributes (rasterio's `Window`; fractional offsets are refused).
pub struct Window((i64, i64, i64, i64));

impl<'a, 'py> FromPyObject<'a, 'py> for Window {
    type Error = PyErr;

    fn extract(ob: pyo3::Borrowed<'a, 'py, PyAny>) -> PyResult<Self> {
        if let Ok(t) = ob.extract::<(i64, i64, i64, i64)>() {
            return Ok(Window(t));
        }
        let field = |name: &str| -> PyResult<i64> {
            let v = ob.getattr(name).map_err(|_| {
                PyCbdamError::Input(
                    "window=: a tuple (col_off, row_off, width, height) or a rasterio Window"
                        .into(),
                )
            })?;
            let f: f64 = v.extract()?;
            if f.fract() != 0.0 {
                return Err(PyCbdamError::Input(format!(
                    "window=: {name}={f} is not a whole number of samples"
                ))
                .into());
            }
            Ok(f as i64)
        };
        Ok(Window((
            field("col_off")?,
            field("row_off")?,
            field("width")?,
            field("height")?,
        )))
    }
}

/// The records a remote reader keeps between reads unless told otherwise: 64 MiB.
const DEFAULT_CACHE_BYTES: i64 = 64 << 20;

/// An open repository (`cbdam.open`).
#[pyclass(module = "cbdam", frozen)]
pub struct Reader {
    source: Source,
    /// The path or URL it was opened from, for messages and `repr`.
    name: String,
}

/// Opens a repository: a local file (memory-mapped), a `cbdam serve` repository URL, or the URL
/// of a `.cbdam` file on a server with Range support. `timeout`: seconds a remote read waits
/// without a record arriving before it raises `NetworkError`. `cache_bytes`: how many bytes of
/// records a remote reader keeps between reads (least recently used dropped first; 0: none).
#[pyfunction]
#[pyo3(signature = (path_or_url, timeout = 10.0, cache_bytes = DEFAULT_CACHE_BYTES))]
pub fn open(
    py: Python<'_>,
    path_or_url: &Bound<'_, PyAny>,
    timeout: f64,
    cache_bytes: i64,
) -> PyResult<Reader> {
    let Ok(cache_bytes) = usize::try_from(cache_bytes) else {
        return Err(PyCbdamError::Input(format!(
            "cache_bytes={cache_bytes}: must be 0 or a positive number of bytes"
        ))
        .into());
    };
    if !(timeout.is_finite() && timeout > 0.0) {
        return Err(PyCbdamError::Input(format!(
            "timeout={timeout}: must be a positive number of seconds"
        ))
        .into());
    }
    let url = path_or_url
        .extract::<String>()
        .ok()
        .filter(|s| s.starts_with("http://") || s.starts_with("https://"));
    let (source, name) = match url {
        Some(url) => {
            let stall = Duration::from_secs_f64(timeout);
            let source = py.detach(|| Source::open_remote(&url, stall, cache_bytes))?;
            (source, url)
        }
        None => {
            let path: PathBuf = path_or_url.extract()?;
            let source = py.detach(|| Source::open_local(&path))?;
            (source, path.display().to_string())
        }
    };
    Ok(Reader { source, name })
}

impl Reader {
    fn is_planet(&self) -> bool {
        self.source.head().params().domain.kind() != DomainKind::Planar
    }

    /// Refuses a planet for the planar reads, naming the planet's.
    fn require_planar(&self) -> Result<()> {
        match self.is_planet() {
            true => Err(PyCbdamError::Unsupported(format!(
                "{} is a planet (cube-sphere): read, sample and to_xarray take planar rasters; \
                 use read_geo(bbox=(west, south, east, north), resolution=degrees) and \
                 sample_geo(lons, lats)",
                self.name
            ))),
            false => Ok(()),
        }
    }

    /// Refuses a plane for the planet's reads.
    fn require_planet(&self, what: &str) -> Result<()> {
        match self.is_planet() {
            true => Ok(()),
            false => Err(PyCbdamError::Unsupported(format!(
                "{} is planar: {what} reads planets (cube-sphere); use read / sample with its \
                 CRS coordinates",
                self.name
            ))),
        }
    }

    /// `level`, checked (an even level of the planet), else the one `resolution` picks.
    fn geo_level(&self, level: Option<u8>, resolution: Option<f64>) -> Result<u8> {
        let head = self.source.head();
        let finest = head.params().layout().finest_level();
        match (level, resolution) {
            (Some(l), _) if l % 2 != 0 || l > finest => Err(PyCbdamError::Input(format!(
                "level={l}: only even levels 0, 2, …, {finest} are grids of this planet"
            ))),
            (Some(l), _) => Ok(l),
            (None, Some(r)) => Ok(planet::level_for(head, r)),
            (None, None) => Ok(finest),
        }
    }

    /// A new array of `shape` of `T` holding the heights at `points`, written in place
    /// without the GIL.
    fn geo_as<'py, T: Sample + numpy::Element, D: numpy::ndarray::Dimension>(
        &self,
        py: Python<'py>,
        shape: D,
        level: u8,
        points: &[(f64, f64)],
    ) -> PyResult<Bound<'py, PyAny>> {
        let array = numpy::PyArray::<T, D>::zeros(py, shape, false);
        {
            let mut rw = array.readwrite();
            let out = rw
                .as_slice_mut()
                .map_err(|e| PyCbdamError::Other(e.to_string()))?;
            py.detach(|| planet::heights_at(&self.source, &self.name, level, points, out))?;
        }
        Ok(array.into_any())
    }

    fn georef(&self) -> Option<&GeoRef> {
        self.source.head().georef()
    }

    fn data_size(&self) -> (i64, i64) {
        let d = self.source.head().params().domain.data();
        (i64::from(d.width), i64::from(d.height))
    }

    /// The samples `level`, `window` or `bbox` ask for, checked (as `cbdam extract` checks them).
    fn level_grid(
        &self,
        level: Option<u8>,
        window: Option<(i64, i64, i64, i64)>,
        bbox: Option<Vec<f64>>,
    ) -> Result<LevelGrid> {
        let head = self.source.head();
        self.require_planar()?;
        let (w, h) = self.data_size();
        let rect = match (window, bbox) {
            (Some(_), Some(_)) => {
                return Err(PyCbdamError::Input(
                    "give window= or bbox=, not both".into(),
                ));
            }
            (Some((col, row, width, height)), None) => {
                if width < 1
                    || height < 1
                    || col < 0
                    || row < 0
                    || col + width > w
                    || row + height > h
                {
                    return Err(PyCbdamError::Input(format!(
                        "window=(col_off={col}, row_off={row}, width={width}, height={height}) \
                         is not inside the {w} × {h} grid (or is empty)"
                    )));
                }
                Some((col, row, col + width - 1, row + height - 1))
            }
            (None, Some(b)) => {
                Some(bbox_window(&b, head.georef(), w, h, "bbox=").map_err(PyCbdamError::Input)?)
            }
            (None, None) => None,
        };
        LevelGrid::new(head.params(), level, rect, "level=").map_err(PyCbdamError::Input)
    }

    /// A new `height × width` array of `T`, decoded into in place without the GIL.
    fn read_as<'py, T: Sample + numpy::Element>(
        &self,
        py: Python<'py>,
        grid: &LevelGrid,
    ) -> PyResult<Bound<'py, PyAny>> {
        let array = PyArray2::<T>::zeros(py, [grid.height, grid.width], false);
        {
            let mut rw = array.readwrite();
            let out = rw
                .as_slice_mut()
                .map_err(|e| PyCbdamError::Other(e.to_string()))?;
            py.detach(|| self.source.read_into(grid, out, &self.name))?;
        }
        Ok(array.into_any())
    }
}

#[pymethods]
impl Reader {
    /// The header as a dict, as `/meta` and `cbdam inspect --json` give it.
    #[getter]
    fn meta<'py>(&self, py: Python<'py>) -> PyResult<Bound<'py, PyAny>> {
        let text = cbdam_server::describe::describe_head(self.source.head()).to_string();
        py.import("json")?.call_method1("loads", (text,))
    }

    /// `(left, bottom, right, top)` of the data in CRS units (the outer edges of the cells, as
    /// rasterio's `bounds`); in pixels `(0, height, width, 0)` without georeferencing.
    #[getter]
    fn bounds(&self) -> (f64, f64, f64, f64) {
        let (w, h) = self.data_size();
        let [a, _, c, _, e, f] = self.transform_of(None);
        let (x0, y0) = (c, f);
        let (x1, y1) = (c + w as f64 * a, f + h as f64 * e);
        (x0.min(x1), y0.min(y1), x0.max(x1), y0.max(y1))
    }

    /// The CRS: `"EPSG:code"`, else its WKT, else `None`.
    #[getter]
    fn crs(&self) -> Option<String> {
        let g = self.georef()?;
        match (g.epsg, &g.wkt) {
            (Some(code), _) => Some(format!("EPSG:{code}")),
            (None, Some(wkt)) => Some(wkt.clone()),
            (None, None) => None,
        }
    }

    /// The affine transform `(a, b, c, d, e, f)` of what `read(level, window)` returns
    /// (rasterio's `Affine` order: x = a·col + b·row + c, y = d·col + e·row + f, from the outer
    /// corner of the north-west cell). Without georeferencing, in the input grid's pixels (x =
    /// column, y = row, sample centres at whole numbers).
    #[pyo3(signature = (level = None, window = None))]
    fn transform(&self, level: Option<u8>, window: Option<Window>) -> PyResult<[f64; 6]> {
        let grid = self.level_grid(level, window.map(|w| w.0), None)?;
        Ok(self.transform_of(Some(&grid)))
    }

    /// `(rows, columns)` of the input grid.
    #[getter]
    fn shape(&self) -> (usize, usize) {
        let (w, h) = self.data_size();
        (h as usize, w as usize)
    }

    /// The levels `read` takes (the even ones, the finest last), a list of ints (PyO3 would
    /// make a `Vec<u8>` a `bytes`).
    #[getter]
    fn levels(&self) -> Vec<u32> {
        let finest = self.source.head().params().layout().finest_level();
        (0..=u32::from(finest)).filter(|l| l % 2 == 0).collect()
    }

    /// The guaranteed maximum error of every decoded height, metres.
    #[getter]
    fn max_error(&self) -> f64 {
        self.source.head().plan().max_error()
    }

    /// `'planar'` or `'cube-sphere'`.
    #[getter]
    fn domain(&self) -> &'static str {
        self.source.head().params().domain.kind().name()
    }

    /// The nodata value the input recorded (reads give NaN there), or `None`.
    #[getter]
    fn nodata(&self) -> Option<f64> {
        self.source.head().nodata()
    }

    /// The grid `(level, step, col_off, row_off, width, height)` a read with these arguments
    /// returns: its level, the spacing of its samples and its first sample in input samples,
    /// and its size.
    #[pyo3(signature = (level = None, window = None, bbox = None))]
    fn grid(
        &self,
        level: Option<u8>,
        window: Option<Window>,
        bbox: Option<Vec<f64>>,
    ) -> PyResult<(u8, i64, i64, i64, usize, usize)> {
        let g = self.level_grid(level, window.map(|w| w.0), bbox)?;
        Ok((g.level, g.step, g.x0, g.y0, g.width, g.height))
    }

    /// Heights in metres as a `height × width` array (row 0 north), NaN where there is no
    /// data: the whole grid, or `window=(col_off, row_off, width, height)` of the input grid's
    /// samples, or the samples whose centres lie in `bbox=(minx, miny, maxx, maxy)` (CRS
    /// units); at the finest level or an even coarser `level` (its samples inside the window,
    /// every 2^((finest − level)/2) input samples). `out_dtype`: 'float32' or 'float64'.
    #[pyo3(signature = (level = None, window = None, bbox = None, out_dtype = "float32"))]
    fn read<'py>(
        &self,
        py: Python<'py>,
        level: Option<u8>,
        window: Option<Window>,
        bbox: Option<Vec<f64>>,
        out_dtype: &str,
    ) -> PyResult<Bound<'py, PyAny>> {
        let grid = self.level_grid(level, window.map(|w| w.0), bbox)?;
        match out_dtype {
            "float32" | "f4" => self.read_as::<f32>(py, &grid),
            "float64" | "f8" => self.read_as::<f64>(py, &grid),
            other => Err(PyCbdamError::Input(format!(
                "out_dtype={other:?}: 'float32' or 'float64'"
            ))
            .into()),
        }
    }

    /// Heights at points `(xs[i], ys[i])` (CRS units; pixels without georeferencing), float64:
    /// bilinear between the finest level's four nearest samples, so within `max_error` of the
    /// same interpolation of the input; NaN outside the grid or next to a sample without data.
    /// Decodes the window that holds all the points.
    fn sample<'py>(
        &self,
        py: Python<'py>,
        xs: PyReadonlyArray1<'py, f64>,
        ys: PyReadonlyArray1<'py, f64>,
    ) -> PyResult<Bound<'py, PyArray1<f64>>> {
        self.require_planar()?;
        // Any strides (a column of a 2-D array, a reversed view): copied once.
        let (xs, ys): (Vec<f64>, Vec<f64>) = (xs.as_array().to_vec(), ys.as_array().to_vec());
        if xs.len() != ys.len() {
            return Err(PyCbdamError::Input(format!(
                "xs and ys differ in length ({} and {})",
                xs.len(),
                ys.len()
            ))
            .into());
        }
        let (w, h) = self.data_size();
        let [a, _, c, _, e, f] = self.transform_of(None);
        // Fractional (column, row) of each point, sample centres at whole numbers.
        let at: Vec<(f64, f64)> = xs
            .iter()
            .zip(&ys)
            .map(|(&x, &y)| ((x - c) / a - 0.5, (y - f) / e - 0.5))
            .collect();
        let inside = |&(col, row): &(f64, f64)| {
            col >= 0.0 && row >= 0.0 && col <= (w - 1) as f64 && row <= (h - 1) as f64
        };
        let mut out = vec![f64::NAN; at.len()];
        let rect = at
            .iter()
            .filter(|p| inside(p))
            .fold(None, |r, &(col, row)| {
                let (c0, r0, c1, r1) = (
                    col.floor() as i64,
                    row.floor() as i64,
                    col.ceil() as i64,
                    row.ceil() as i64,
                );
                Some(match r {
                    None => (c0, r0, c1, r1),
                    Some((a0, b0, a1, b1)) => (c0.min(a0), r0.min(b0), c1.max(a1), r1.max(b1)),
                })
            });
        if let Some(rect) = rect {
            let grid = LevelGrid::new(self.source.head().params(), None, Some(rect), "level=")
                .map_err(PyCbdamError::Input)?;
            let mut values = vec![0f64; grid.width * grid.height];
            py.detach(|| self.source.read_into(&grid, &mut values, &self.name))?;
            for (o, p) in out.iter_mut().zip(&at) {
                if inside(p) {
                    *o = bilinear(&values, &grid, *p);
                }
            }
        }
        Ok(PyArray1::from_vec(py, out))
    }

    /// A planet's heights on a latitude/longitude grid: the cells of `bbox=(west, south, east,
    /// north)` (degrees, sides whole numbers of cells) at `resolution` degrees, each sampled
    /// at its centre, row 0 north (the transform `(resolution, 0, west, 0, −resolution,
    /// north)` in EPSG:4326). From `level` (default: the coarsest even level whose mean
    /// spacing is at most `resolution`), bilinear in a face's lattice, as `sample_geo`.
    #[pyo3(signature = (bbox, resolution, level = None, out_dtype = "float32"))]
    fn read_geo<'py>(
        &self,
        py: Python<'py>,
        bbox: Vec<f64>,
        resolution: f64,
        level: Option<u8>,
        out_dtype: &str,
    ) -> PyResult<Bound<'py, PyAny>> {
        self.require_planet("read_geo")?;
        let grid = GeoGrid::new(&bbox, resolution)?;
        let level = self.geo_level(level, Some(resolution))?;
        let points = grid.points();
        let shape = numpy::ndarray::Ix2(grid.height, grid.width);
        match out_dtype {
            "float32" | "f4" => self.geo_as::<f32, _>(py, shape, level, &points),
            "float64" | "f8" => self.geo_as::<f64, _>(py, shape, level, &points),
            other => Err(PyCbdamError::Input(format!(
                "out_dtype={other:?}: 'float32' or 'float64'"
            ))
            .into()),
        }
    }

    /// A planet's heights (float64, metres) at geodetic `(lons[i], lats[i])`, degrees:
    /// bilinear between the four lattice points of the finest level (or `level`) around each
    /// on its face, so within `max_error` of the same interpolation of the planet's resampled
    /// lattice, and within `max_error + resampling_error[0]` of the input at the input's
    /// samples. NaN where the planet has no data. Decodes the faces' rectangles around the
    /// points.
    #[pyo3(signature = (lons, lats, level = None))]
    fn sample_geo<'py>(
        &self,
        py: Python<'py>,
        lons: PyReadonlyArray1<'py, f64>,
        lats: PyReadonlyArray1<'py, f64>,
        level: Option<u8>,
    ) -> PyResult<Bound<'py, PyAny>> {
        self.require_planet("sample_geo")?;
        let (lons, lats) = (lons.as_array(), lats.as_array());
        let points = planet::lon_lat_points(lons.iter(), lats.iter())?;
        let level = self.geo_level(level, None)?;
        let shape = numpy::ndarray::Ix1(points.len());
        self.geo_as::<f64, _>(py, shape, level, &points)
    }

    /// A planet's resampling error `(max, rms)`, metres: how far its lattice is from the
    /// inputs' samples (each against the bilinear interpolation of the four lattice points
    /// around it), as the build measured it; `None` for planes and planets without it.
    #[getter]
    fn resampling_error(&self) -> Option<(f64, f64)> {
        let p = self.source.head().provenance()?;
        Some((p.resampling_max, p.resampling_rms))
    }

    /// A remote reader's cache: `{'records', 'bytes', 'limit', 'hits', 'misses'}` (records
    /// held, their bytes, the budget, and since opening the records reads found held and those
    /// they fetched); `None` for a local file.
    fn cache_info<'py>(&self, py: Python<'py>) -> PyResult<Option<Bound<'py, PyDict>>> {
        let Some(info) = self.source.cache_info() else {
            return Ok(None);
        };
        let d = PyDict::new(py);
        d.set_item("records", info.records)?;
        d.set_item("bytes", info.bytes)?;
        d.set_item("limit", info.limit)?;
        d.set_item("hits", info.hits)?;
        d.set_item("misses", info.misses)?;
        Ok(Some(d))
    }

    fn __repr__(&self) -> String {
        let (rows, cols) = self.shape();
        format!(
            "<cbdam.Reader {} {}: {rows} × {cols}, levels {:?}, max error {} m>",
            self.name,
            self.domain(),
            self.levels(),
            self.max_error()
        )
    }
}

impl Reader {
    /// The affine transform of `grid` (default: the finest level, whole): in pixels, rows
    /// south, without georeferencing.
    fn transform_of(&self, grid: Option<&LevelGrid>) -> [f64; 6] {
        let finest = match grid {
            Some(_) => None,
            None => LevelGrid::new(self.source.head().params(), None, None, "").ok(),
        };
        let Some(grid) = grid.or(finest.as_ref()) else {
            return [1.0, 0.0, 0.0, 0.0, 1.0, 0.0];
        };
        let step = grid.step as f64;
        let Some(g) = self.georef() else {
            // Pixel (column, row) coordinates of the input grid, sample centres at +0.5.
            let (x0, y0) = (grid.x0 as f64 - step / 2.0, grid.y0 as f64 - step / 2.0);
            return [step, 0.0, x0, 0.0, step, y0];
        };
        let g = grid.georef(g);
        // A PixelIsPoint origin is a sample's centre: the cell's outer corner is half a cell
        // away (GDAL's convention).
        let half = if g.pixel_is_area { 0.0 } else { 0.5 };
        [
            g.pixel_x,
            0.0,
            g.origin_x - half * g.pixel_x,
            0.0,
            -g.pixel_y,
            g.origin_y + half * g.pixel_y,
        ]
    }
}

/// Bilinear interpolation of the finest-level `values` (of `grid`, step 1) at fractional
/// `(column, row)` of the input grid; samples with zero weight are not read, so a point on a
/// sample is that sample even beside nodata.
fn bilinear(values: &[f64], grid: &LevelGrid, (col, row): (f64, f64)) -> f64 {
    let (c0, r0) = (col.floor(), row.floor());
    let (fx, fy) = (col - c0, row - r0);
    let (c0, r0) = (c0 as i64, r0 as i64);
    let mut sum = 0.0;
    for (dc, dr, weight) in [
        (0, 0, (1.0 - fx) * (1.0 - fy)),
        (1, 0, fx * (1.0 - fy)),
        (0, 1, (1.0 - fx) * fy),
        (1, 1, fx * fy),
    ] {
        if weight == 0.0 {
            continue;
        }
        match grid.index_of(c0 + dc, r0 + dr) {
            Some(i) => sum += weight * values[i],
            None => return f64::NAN,
        }
    }
    sum
}
