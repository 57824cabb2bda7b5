//! Where a repository lies on the Earth, for web maps: geodetic latitude / longitude → a
//! lattice position of the repository (face, x, y), its bounds, and its finest sample spacing
//! in metres.
//!
//! Three kinds of repository can be placed: planets (cube-sphere on WGS84), planes
//! georeferenced in EPSG:4326 (latitude / longitude on WGS84), and planes in a UTM zone (EPSG
//! 326zz / 327zz WGS84, 269zz NAD83, 258zz ETRS89, through `cbdam_codec`'s Krüger series).
//! Every other CRS is refused by name.

use cbdam_codec::geodesy::cube_map::{face_st_to_lat_lon, lat_lon_to_face_st};
use cbdam_codec::geodesy::{LatLon, Utm, wgs84};
use cbdam_codec::repository::{GeoRef, RepositoryHead};

use crate::TilesError;

/// Metres of one degree of latitude (the meridian arc's mean) and of longitude at the equator.
const METRES_PER_DEGREE_LAT: f64 = 111_132.954;
const METRES_PER_DEGREE_LON: f64 = wgs84::A * std::f64::consts::PI / 180.0;

/// How latitude / longitude map to a repository's lattice.
#[derive(Clone, Debug)]
pub enum Placement {
    /// A cube-sphere whose faces have `side` lattice steps a side.
    Planet {
        /// `S`.
        side: i64,
    },
    /// A plane whose model coordinates are longitude (x) and latitude (y), degrees.
    Geographic {
        /// The georeferencing.
        georef: GeoRef,
        /// Data samples, columns and rows.
        size: (usize, usize),
    },
    /// A plane in a UTM zone, easting (x) and northing (y), metres.
    Utm {
        /// The zone.
        utm: Utm,
        /// The georeferencing.
        georef: GeoRef,
        /// Data samples, columns and rows.
        size: (usize, usize),
    },
}

impl Placement {
    /// The placement of a repository, or why it has none.
    pub fn of(head: &RepositoryHead) -> Result<Placement, TilesError> {
        let p = head.params();
        if p.kind != cbdam_codec::hierarchy::RepoKind::Elevation {
            return Err(TilesError::Unsupported(
                "this is a colour repository: elevation tiles need heights".into(),
            ));
        }
        if let Some(cube) = p.domain.cube() {
            return Ok(Placement::Planet { side: cube.side() });
        }
        let size = p.domain.data().size();
        let Some(georef) = head.georef() else {
            return Err(TilesError::Unsupported(
                "the repository is not georeferenced: web-map tiles need to know where it lies"
                    .into(),
            ));
        };
        match georef.epsg {
            Some(4326) => Ok(Placement::Geographic {
                georef: georef.clone(),
                size,
            }),
            Some(code) => match Utm::from_epsg(code) {
                Some(utm) => Ok(Placement::Utm {
                    utm,
                    georef: georef.clone(),
                    size,
                }),
                None => Err(TilesError::Unsupported(format!(
                    "the repository is in EPSG:{code}; web-map tiles are made from EPSG:4326, \
                     UTM zones (EPSG 326zz, 327zz, 269zz, 258zz) and planets only"
                ))),
            },
            None => Err(TilesError::Unsupported(
                "the repository's CRS has no EPSG code (only a WKT definition); web-map tiles \
                 are made from EPSG:4326, UTM zones and planets only"
                    .into(),
            )),
        }
    }

    /// The lattice position `(face, x, y)` (finest-level units, fractional) of a geodetic
    /// point; `None` where the repository's CRS cannot place it (beyond 30° of a UTM zone's
    /// central meridian).
    pub fn locate(&self, lat: f64, lon: f64) -> Option<(u8, f64, f64)> {
        match self {
            Placement::Planet { side } => {
                let (face, s, t) = lat_lon_to_face_st(LatLon { lat, lon });
                Some((face, s * *side as f64, t * *side as f64))
            }
            Placement::Geographic { georef, size } => {
                let (c, r) = model_to_lattice(georef, lon, lat);
                // A longitude one turn away may be the one the data uses (0 … 360 data).
                let inside = |c: f64| (-0.5..=size.0 as f64 - 0.5).contains(&c);
                let turn = 360.0 / georef.pixel_x;
                let c = [c, c + turn, c - turn]
                    .into_iter()
                    .find(|&c| inside(c))
                    .unwrap_or(c);
                Some((0, c, r))
            }
            Placement::Utm { utm, georef, .. } => {
                let mut d = lon - utm.central_meridian();
                d -= 360.0 * (d / 360.0).round();
                if d.abs() > 30.0 {
                    return None;
                }
                let (e, n) = utm.forward(LatLon { lat, lon });
                let (c, r) = model_to_lattice(georef, e, n);
                Some((0, c, r))
            }
        }
    }

    /// The geodetic point of lattice position `(face, x, y)`.
    pub fn lat_lon(&self, face: u8, x: f64, y: f64) -> LatLon {
        match self {
            Placement::Planet { side } => {
                let s = *side as f64;
                face_st_to_lat_lon(face, x / s, y / s)
            }
            Placement::Geographic { georef, .. } => {
                let (lon, lat) = lattice_to_model(georef, x, y);
                LatLon { lat, lon }
            }
            Placement::Utm { utm, georef, .. } => {
                let (e, n) = lattice_to_model(georef, x, y);
                utm.inverse(e, n)
            }
        }
    }

    /// West, south, east, north of the data in degrees: the outer edges of its edge samples
    /// (half a sample beyond their centres); the whole Earth for a planet.
    pub fn bounds(&self) -> [f64; 4] {
        let size = match self {
            Placement::Planet { .. } => return [-180.0, -90.0, 180.0, 90.0],
            Placement::Geographic { size, .. } | Placement::Utm { size, .. } => *size,
        };
        let (w, h) = (size.0 as f64 - 0.5, size.1 as f64 - 0.5);
        // Along the rectangle's outline: a UTM rectangle is curved in latitude / longitude.
        let steps = 64;
        let mut b = [
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        ];
        for k in 0..=steps {
            let t = k as f64 / steps as f64;
            let along_x = -0.5 + t * (w + 0.5);
            let along_y = -0.5 + t * (h + 0.5);
            for (x, y) in [(along_x, -0.5), (along_x, h), (-0.5, along_y), (w, along_y)] {
                let ll = self.lat_lon(0, x, y);
                b = [
                    b[0].min(ll.lon),
                    b[1].min(ll.lat),
                    b[2].max(ll.lon),
                    b[3].max(ll.lat),
                ];
            }
        }
        [
            b[0].max(-180.0),
            b[1].max(-90.0),
            b[2].min(180.0),
            b[3].min(90.0),
        ]
    }

    /// The finest level's sample spacing on the ground, metres: the geometric mean of the two
    /// axes' at the data's centre (a planet: a quarter meridian over `S`, the mean of a face).
    pub fn spacing_m(&self) -> f64 {
        match self {
            Placement::Planet { side } => std::f64::consts::FRAC_PI_2 * wgs84::A / *side as f64,
            Placement::Geographic { georef, .. } => {
                let [_, s, _, n] = self.bounds();
                let lat = 0.5 * (s + n);
                let dx = georef.pixel_x.abs() * METRES_PER_DEGREE_LON * lat.to_radians().cos();
                let dy = georef.pixel_y.abs() * METRES_PER_DEGREE_LAT;
                (dx.max(1e-3) * dy).sqrt()
            }
            Placement::Utm { georef, .. } => (georef.pixel_x * georef.pixel_y).abs().sqrt(),
        }
    }
}

/// Lattice column and row (sample centres at integers, row 0 = north) of model point `(mx, my)`.
fn model_to_lattice(g: &GeoRef, mx: f64, my: f64) -> (f64, f64) {
    let half = if g.pixel_is_area { 0.5 } else { 0.0 };
    (
        (mx - g.origin_x) / g.pixel_x - half,
        (g.origin_y - my) / g.pixel_y - half,
    )
}

/// Model point of lattice column and row `(x, y)`.
fn lattice_to_model(g: &GeoRef, x: f64, y: f64) -> (f64, f64) {
    let half = if g.pixel_is_area { 0.5 } else { 0.0 };
    (
        g.origin_x + (x + half) * g.pixel_x,
        g.origin_y - (y + half) * g.pixel_y,
    )
}

/// The desired level step for a ground spacing of `metres`: the coarsest level (index into
/// [`crate::surface::Surface::levels`]) whose samples are at most `metres` apart.
pub fn coarsen_for(spacing_m: f64, metres: f64) -> usize {
    if metres.is_nan() || metres <= spacing_m {
        return 0;
    }
    (metres / spacing_m).log2().floor() as usize
}
