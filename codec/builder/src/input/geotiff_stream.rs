//! GeoTIFF samples decoded strip by strip or tile by tile, in parallel, a band of rows at a time.
//!
//! A strip is a tile as wide as the image, so both layouts are one grid of chunks here: a band
//! is one or more whole rows of chunks, decoded concurrently (each worker with its own decoder
//! and file handle: the `tiff` decoder reads through `&mut self`), then copied row by row into
//! the `f64` samples a [`SampleSource`] pass hands out. Memory is one band, whatever the file's
//! size, unless the file itself stores the image as one huge strip.
//!
//! Planning and quantizing take two passes. Decompressing (and undoing the floating-point
//! predictor) costs as much as everything else done to a sample before the encoder, so a file
//! whose decoded samples fit in [`CACHE_BYTES`] is decoded once and its chunks kept for the
//! later passes; larger files are decoded on every pass and stay within one band.
//!
//! [`read`] decodes a whole image through the same source.

use std::fs::File;
use std::io::{BufReader, ErrorKind};
use std::path::{Path, PathBuf};
use std::sync::{Mutex, OnceLock};

use rayon::prelude::*;
use tiff::decoder::{Decoder, DecodingResult};

use super::geotiff::{Header, tiff_err};
use super::stream::BLOCK_SAMPLES;
use super::{Dem, GeoRef, Limits, SampleType};
use cbdam_codec::CodecError;
use cbdam_codec::samples::{BlockFn, SampleSource};

/// Most bytes of decoded samples kept between passes (see the module notes): 64 M samples of
/// float32, which the grid being built (5 bytes a sample) already outweighs.
pub const CACHE_BYTES: usize = 256 << 20;

/// A GeoTIFF (or plain TIFF) read in bands of rows on every pass; see the module notes.
pub struct GeoTiffSource {
    path: PathBuf,
    header: Header,
    /// Rows of chunks per band.
    band_chunk_rows: usize,
    /// Whether the decoded chunks fit in [`CACHE_BYTES`] and are kept after the first pass.
    caching: bool,
    /// Every band's decoded chunks, once a whole pass has run.
    cache: OnceLock<Vec<Vec<DecodingResult>>>,
}

impl std::fmt::Debug for GeoTiffSource {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("GeoTiffSource")
            .field("path", &self.path)
            .field("header", &self.header)
            .field("band_chunk_rows", &self.band_chunk_rows)
            .field("caching", &self.caching)
            .field("cached", &self.cache.get().is_some())
            .finish()
    }
}

/// A decoder per worker, reused across the chunks of a pass.
type TiffDecoder = Decoder<BufReader<File>>;

impl GeoTiffSource {
    /// Opens `path`, checking its tags and chunk table like [`super::read_dem`] does; `nodata`
    /// overrides the file's nodata value.
    pub fn open(path: &Path, nodata: Option<f64>, limits: &Limits) -> Result<Self, CodecError> {
        cbdam_codec::files::check_regular_file(path)?;
        let mut header = Header::read(path, limits)?;
        if nodata.is_some() {
            header.nodata = nodata;
        }
        super::check_nodata(header.nodata, path)?;
        let band_rows = (BLOCK_SAMPLES / header.width.max(1)).max(1);
        let band_chunk_rows = (band_rows / header.chunk_height).max(1);
        // Padding of edge tiles is decoded too; the bound is on what is held, padding included.
        let decoded = (header.chunks_across * header.chunk_width)
            .saturating_mul(header.chunks_down * header.chunk_height)
            .saturating_mul(header.sample_type.bytes());
        Ok(Self {
            path: path.to_path_buf(),
            header,
            band_chunk_rows,
            caching: decoded <= CACHE_BYTES,
            cache: OnceLock::new(),
        })
    }

    /// Keeps (`true`) or never keeps (`false`) the decoded chunks between passes, whatever
    /// [`CACHE_BYTES`] says; the samples are the same either way.
    pub fn set_caching(&mut self, caching: bool) {
        self.caching = caching;
        self.cache = OnceLock::new();
    }

    /// Georeferencing of the file, if it carries any.
    pub fn georef(&self) -> Option<&GeoRef> {
        self.header.georef.as_ref()
    }

    /// Whether the file is tiled (otherwise stripped).
    pub fn is_tiled(&self) -> bool {
        self.header.tiled
    }

    /// Rows per chunk (strip, or row of tiles): [`GeoTiffSource::read_rows`] decodes whole
    /// chunks, so reads of rows aligned to this decode each chunk once.
    pub fn chunk_rows(&self) -> usize {
        self.header.chunk_height
    }

    /// Rows `rows` into `out` (replacing its contents), row-major, each sample converted exactly
    /// to `f64`: the chunks covering them are decoded, in parallel, and dropped. What a mosaic
    /// reads of one tile at a time, without a pass over the whole file.
    pub fn read_rows(
        &self,
        rows: std::ops::Range<usize>,
        out: &mut Vec<f64>,
    ) -> Result<(), CodecError> {
        let h = &self.header;
        if rows.start >= rows.end || rows.end > h.height {
            return Err(CodecError::invalid(format!(
                "rows {}..{} of a {}-row image",
                rows.start, rows.end, h.height
            )));
        }
        let (c0, c1) = (
            rows.start / h.chunk_height,
            (rows.end - 1) / h.chunk_height + 1,
        );
        let first = c0 * h.chunks_across;
        let pool = Mutex::new(Vec::new());
        let chunks = (first..c1 * h.chunks_across)
            .into_par_iter()
            .map(|i| self.decode_chunk(&pool, i))
            .collect::<Result<Vec<_>, CodecError>>()?;
        out.clear();
        out.resize(rows.len() * h.width, 0.0);
        out.par_chunks_mut(h.width).zip(rows).for_each(|(row, y)| {
            let (band_row, in_chunk) = (y / h.chunk_height - c0, y % h.chunk_height);
            for c in 0..h.chunks_across {
                let k = band_row * h.chunks_across + c;
                let (x0, _, w, _) = h.chunk_rect(first + k);
                widen(&chunks[k], in_chunk * w, &mut row[x0..x0 + w]);
            }
        });
        Ok(())
    }

    fn what(&self) -> &'static str {
        if self.header.tiled { "tile" } else { "strip" }
    }

    fn open_decoder(&self) -> Result<TiffDecoder, CodecError> {
        let file = File::open(&self.path)?;
        let mut dec = Decoder::new(BufReader::new(file))
            .map_err(tiff_err)?
            .with_limits(self.header.decoder_limits());
        let (w, h) = dec.dimensions().map_err(tiff_err)?;
        if (w as usize, h as usize) != (self.header.width, self.header.height) {
            return Err(CodecError::corrupt(format!(
                "the file changed while being read: now {w} x {h} samples, was {} x {}",
                self.header.width, self.header.height
            )));
        }
        Ok(dec)
    }

    /// Decodes chunk `index`, checking it holds exactly the samples its place in the grid
    /// calls for; errors name the chunk and the rows it covers.
    fn decode_chunk(
        &self,
        pool: &Mutex<Vec<TiffDecoder>>,
        index: usize,
    ) -> Result<DecodingResult, CodecError> {
        let h = &self.header;
        let (x0, y0, w, rows) = h.chunk_rect(index);
        let context = |e: CodecError| {
            let columns = if h.tiled {
                format!(", columns {x0}..{}", x0 + w)
            } else {
                String::new()
            };
            with_context(
                e,
                &format!(
                    "{}: TIFF {} {index} (rows {y0}..{}{columns})",
                    self.path.display(),
                    self.what(),
                    y0 + rows
                ),
            )
        };
        let taken = pool.lock().unwrap_or_else(|e| e.into_inner()).pop();
        let mut dec = match taken {
            Some(d) => d,
            None => self.open_decoder().map_err(context)?,
        };
        let chunk = u32::try_from(index).map_err(|_| CodecError::limit("too many chunks"))?;
        let result = dec.read_chunk(chunk).map_err(|e| context(tiff_err(e)))?;
        // A decoder that failed may be mid-stream; only a good one goes back to the pool.
        pool.lock().unwrap_or_else(|e| e.into_inner()).push(dec);
        let len = decoded_len(&result).ok_or_else(|| {
            context(CodecError::unsupported(
                "TIFF sample type beyond 32-bit integers is not supported",
            ))
        })?;
        if len != w * rows {
            return Err(context(CodecError::corrupt(format!(
                "decoded {len} samples where {w} x {rows} were expected"
            ))));
        }
        Ok(result)
    }
}

impl SampleSource for GeoTiffSource {
    fn width(&self) -> usize {
        self.header.width
    }
    fn height(&self) -> usize {
        self.header.height
    }
    fn sample_type(&self) -> SampleType {
        self.header.sample_type
    }
    fn nodata(&self) -> Option<f64> {
        self.header.nodata
    }
    fn for_each_block(&self, f: &mut BlockFn<'_>) -> Result<(), CodecError> {
        let h = &self.header;
        let cached = self.cache.get();
        let mut kept = Vec::new();
        let pool = Mutex::new(Vec::new());
        let mut samples = Vec::new();
        let (mut band, mut chunk_row) = (0, 0);
        while chunk_row < h.chunks_down {
            let end = (chunk_row + self.band_chunk_rows).min(h.chunks_down);
            let first = chunk_row * h.chunks_across;
            let decoded = match cached {
                Some(_) => None,
                None => Some(
                    (first..end * h.chunks_across)
                        .into_par_iter()
                        .map(|i| self.decode_chunk(&pool, i))
                        .collect::<Result<Vec<_>, CodecError>>()?,
                ),
            };
            let chunks = match (cached, &decoded) {
                (Some(bands), _) => &bands[band],
                (None, Some(d)) => d,
                (None, None) => unreachable!("decoded when not cached"),
            };
            let y0 = chunk_row * h.chunk_height;
            let y1 = (end * h.chunk_height).min(h.height);
            samples.resize((y1 - y0) * h.width, 0.0);
            samples
                .par_chunks_mut(h.width)
                .enumerate()
                .for_each(|(r, row)| {
                    let (band_row, in_chunk) = (r / h.chunk_height, r % h.chunk_height);
                    for c in 0..h.chunks_across {
                        let (x0, _, w, _) = h.chunk_rect(first + band_row * h.chunks_across + c);
                        let chunk = &chunks[band_row * h.chunks_across + c];
                        widen(chunk, in_chunk * w, &mut row[x0..x0 + w]);
                    }
                });
            if let (Some(d), true) = (decoded, self.caching) {
                kept.push(d);
            }
            f(y0, &samples)?;
            chunk_row = end;
            band += 1;
        }
        if cached.is_none() && self.caching {
            // Only a complete pass is kept; a pass stopped by its callback leaves no cache.
            let _ = self.cache.set(kept);
        }
        Ok(())
    }
}

/// Samples in a decoded chunk, `None` for types no DEM reader accepts.
fn decoded_len(r: &DecodingResult) -> Option<usize> {
    Some(match r {
        DecodingResult::I8(v) => v.len(),
        DecodingResult::U8(v) => v.len(),
        DecodingResult::I16(v) => v.len(),
        DecodingResult::U16(v) => v.len(),
        DecodingResult::I32(v) => v.len(),
        DecodingResult::U32(v) => v.len(),
        DecodingResult::F32(v) => v.len(),
        DecodingResult::F64(v) => v.len(),
        _ => return None,
    })
}

/// Copies `out.len()` samples of `chunk` from `start` on, each converted exactly to `f64`.
fn widen(chunk: &DecodingResult, start: usize, out: &mut [f64]) {
    fn copy<T: Copy + Into<f64>>(src: &[T], out: &mut [f64]) {
        for (o, &s) in out.iter_mut().zip(src) {
            *o = s.into();
        }
    }
    let end = start + out.len();
    match chunk {
        DecodingResult::I8(v) => copy(&v[start..end], out),
        DecodingResult::U8(v) => copy(&v[start..end], out),
        DecodingResult::I16(v) => copy(&v[start..end], out),
        DecodingResult::U16(v) => copy(&v[start..end], out),
        DecodingResult::I32(v) => copy(&v[start..end], out),
        DecodingResult::U32(v) => copy(&v[start..end], out),
        DecodingResult::F32(v) => copy(&v[start..end], out),
        DecodingResult::F64(v) => out.copy_from_slice(&v[start..end]),
        // Refused by `decode_chunk` before any copy.
        _ => unreachable!("chunk types are checked when decoded"),
    }
}

/// `e` with `context` (the file and chunk) in front of its message.
fn with_context(e: CodecError, context: &str) -> CodecError {
    match e {
        CodecError::Io(io) => {
            let kind = io.kind();
            let msg = format!("{context}: {io}");
            if kind == ErrorKind::UnexpectedEof {
                CodecError::truncated(msg)
            } else if kind == ErrorKind::InvalidData {
                // What the decompressors report for a damaged stream.
                CodecError::corrupt(msg)
            } else {
                CodecError::Io(std::io::Error::new(kind, msg))
            }
        }
        CodecError::Corrupt(m) => CodecError::corrupt(format!("{context}: {m}")),
        CodecError::Truncated(m) => CodecError::truncated(format!("{context}: {m}")),
        CodecError::Unsupported(m) => CodecError::unsupported(format!("{context}: {m}")),
        CodecError::InvalidParameter(m) => CodecError::invalid(format!("{context}: {m}")),
        CodecError::LimitExceeded(m) => CodecError::limit(format!("{context}: {m}")),
    }
}

/// The whole image, decoded through [`GeoTiffSource`] (in parallel, chunk by chunk).
pub(super) fn read(path: &Path, limits: &Limits) -> Result<Dem, CodecError> {
    let mut src = GeoTiffSource::open(path, None, limits)?;
    // One pass: keeping the chunks would only double the memory.
    src.set_caching(false);
    let (width, height) = (src.width(), src.height());
    let mut values = Vec::with_capacity(width * height);
    src.for_each_block(&mut |_, block| {
        values.extend_from_slice(block);
        Ok(())
    })?;
    Ok(Dem {
        width,
        height,
        values,
        sample_type: src.sample_type(),
        nodata: src.nodata(),
        georef: src.georef().cloned(),
    })
}
