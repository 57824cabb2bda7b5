//! A rendered flight (`frame_00000.png`, `frame_00001.png`, … of `cbdam render --path`) as one
//! video a user can open: an H.264 MP4 made by `ffmpeg` when it is on the PATH, else an animated
//! PNG (APNG, which browsers and most image viewers play) written here.
//!
//! The APNG is lossless, so it is kept to a reasonable size by its frame size and rate: frames
//! are halved (2×2 pixel means) until they are at most [`APNG_MAX_WIDTH`] pixels wide, and a
//! flight of more than [`APNG_ALL_FRAMES`] frames keeps every second one (15 frames a second of
//! a 30 fps flight still reads as motion). The demo's 451 frames of 640×360 become 226 frames of
//! 320×180.

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use anyhow::{Context, Result, anyhow, bail};

/// Widest frame of an APNG, pixels.
pub const APNG_MAX_WIDTH: u32 = 480;
/// Longest flight whose every frame goes into an APNG.
pub const APNG_ALL_FRAMES: usize = 60;

/// What [`write_flight`] wrote.
#[derive(Debug)]
pub struct Video {
    /// `STEM.mp4` or `STEM.png`.
    pub path: PathBuf,
    /// Format, frames, size and rate, for the user.
    pub description: String,
}

/// The frames `frame_00000.png`, `frame_00001.png`, … in `dir`, from the first up to the first
/// missing number.
pub fn frames_in(dir: &Path) -> Vec<PathBuf> {
    (0..)
        .map(|i| dir.join(format!("frame_{i:05}.png")))
        .take_while(|p| p.is_file())
        .collect()
}

/// Writes the flight whose frames are in `dir` (at `fps` frames a second) as `STEM.mp4` when
/// `ffmpeg` is on the PATH and encodes it, else as the APNG `STEM.png`. An `ffmpeg` that fails
/// is reported on stderr and the APNG is written instead.
pub fn write_flight(dir: &Path, fps: f64, stem: &Path) -> Result<Video> {
    let frames = frames_in(dir);
    if frames.is_empty() {
        bail!("no frame_00000.png in {}", dir.display());
    }
    let mp4 = stem.with_extension("mp4");
    match write_mp4(dir, frames.len(), fps, &mp4) {
        Ok(true) => {
            return Ok(Video {
                description: format!("H.264 MP4, {} frames at {fps} fps", frames.len()),
                path: mp4,
            });
        }
        Ok(false) => {}
        Err(e) => eprintln!("cbdam: warning: {e:#}; writing an animated PNG instead"),
    }
    let png = stem.with_extension("png");
    let (count, (w, h), rate) = write_apng(&frames, fps, &png)?;
    Ok(Video {
        path: png,
        description: format!("animated PNG, {count} frames of {w}×{h} at {rate} fps"),
    })
}

/// Encodes the frames with `ffmpeg` (H.264, yuv420p, sizes padded to even): `Ok(false)` when
/// there is no `ffmpeg` to run.
fn write_mp4(dir: &Path, count: usize, fps: f64, out: &Path) -> Result<bool> {
    let tmp = out.with_extension("mp4.tmp");
    let result = Command::new("ffmpeg")
        .args(["-y", "-nostdin", "-loglevel", "error", "-framerate"])
        .arg(fps.to_string())
        .arg("-i")
        .arg(dir.join("frame_%05d.png"))
        .args(["-frames:v", &count.to_string()])
        .args(["-c:v", "libx264", "-pix_fmt", "yuv420p"])
        .args([
            "-vf",
            "pad=ceil(iw/2)*2:ceil(ih/2)*2",
            "-movflags",
            "+faststart",
        ])
        .args(["-f", "mp4"])
        .arg(&tmp)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::piped())
        .output();
    let output = match result {
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(false),
        other => other.context("running ffmpeg")?,
    };
    if !output.status.success() {
        let _ = std::fs::remove_file(&tmp);
        return Err(anyhow!(
            "ffmpeg could not encode the flight ({}): {}",
            output.status,
            String::from_utf8_lossy(&output.stderr).trim()
        ));
    }
    std::fs::rename(&tmp, out).with_context(|| format!("writing {}", out.display()))?;
    Ok(true)
}

/// Writes `frames` as an APNG at `out` (atomically), looping; returns the frames written, their
/// size and their rate.
pub fn write_apng(frames: &[PathBuf], fps: f64, out: &Path) -> Result<(usize, (u32, u32), f64)> {
    let step = if frames.len() > APNG_ALL_FRAMES { 2 } else { 1 };
    let kept: Vec<&PathBuf> = frames.iter().step_by(step).collect();
    let first = read_rgba(kept[0])?;
    let halvings = halvings(first.0);
    let size = (first.0 >> halvings, first.1 >> halvings);
    // Frame delay in milliseconds (the format's numerator and denominator are 16-bit).
    let delay_ms = (1000.0 * step as f64 / fps).round().clamp(1.0, 65535.0) as u16;
    cbdam_codec::atomic::write_atomically::<anyhow::Error>(out, |file| {
        let mut encoder = png::Encoder::new(std::io::BufWriter::new(file), size.0, size.1);
        encoder.set_color(png::ColorType::Rgba);
        encoder.set_depth(png::BitDepth::Eight);
        encoder.set_compression(png::Compression::High);
        encoder.set_animated(kept.len() as u32, 0)?;
        encoder.set_frame_delay(delay_ms, 1000)?;
        let mut writer = encoder.write_header()?;
        for (i, path) in kept.iter().enumerate() {
            let (w, h, mut rgba) = if i == 0 {
                first.clone()
            } else {
                read_rgba(path)?
            };
            if (w, h) != (first.0, first.1) {
                bail!(
                    "{} is {w}×{h}, the first frame {}×{}",
                    path.display(),
                    first.0,
                    first.1
                );
            }
            let (mut w, mut h) = (w, h);
            for _ in 0..halvings {
                (w, h, rgba) = halve(w, h, &rgba);
            }
            writer.write_image_data(&rgba)?;
        }
        writer.finish()?;
        Ok(())
    })
    .with_context(|| format!("writing {}", out.display()))?;
    Ok((kept.len(), size, fps / step as f64))
}

/// How many times a frame `width` pixels wide is halved to be at most [`APNG_MAX_WIDTH`].
fn halvings(width: u32) -> u32 {
    let mut n = 0;
    while width >> n > APNG_MAX_WIDTH {
        n += 1;
    }
    n
}

/// A PNG's pixels as RGBA8: width, height, pixels.
fn read_rgba(path: &Path) -> Result<(u32, u32, Vec<u8>)> {
    let read = || -> Result<(u32, u32, Vec<u8>)> {
        let file = std::io::BufReader::new(std::fs::File::open(path)?);
        let mut decoder = png::Decoder::new(file);
        decoder.set_transformations(png::Transformations::EXPAND | png::Transformations::STRIP_16);
        let mut reader = decoder.read_info()?;
        let mut buf = vec![0; reader.output_buffer_size().context("frame too large")?];
        let info = reader.next_frame(&mut buf)?;
        buf.truncate(info.buffer_size());
        let rgba = match info.color_type {
            png::ColorType::Rgba => buf,
            png::ColorType::Rgb => buf
                .chunks_exact(3)
                .flat_map(|p| [p[0], p[1], p[2], 255])
                .collect(),
            png::ColorType::Grayscale => buf.iter().flat_map(|&g| [g, g, g, 255]).collect(),
            png::ColorType::GrayscaleAlpha => buf
                .chunks_exact(2)
                .flat_map(|p| [p[0], p[0], p[0], p[1]])
                .collect(),
            png::ColorType::Indexed => bail!("palette left after expansion"),
        };
        Ok((info.width, info.height, rgba))
    };
    read().with_context(|| format!("reading {}", path.display()))
}

/// The image at half size, each pixel the rounded mean of a 2×2 block (an odd last row or
/// column is dropped).
fn halve(w: u32, h: u32, rgba: &[u8]) -> (u32, u32, Vec<u8>) {
    let (hw, hh) = (w / 2, h / 2);
    let mut out = Vec::with_capacity((4 * hw * hh) as usize);
    let at = |x: u32, y: u32, c: usize| u32::from(rgba[4 * (y * w + x) as usize + c]);
    for y in 0..hh {
        for x in 0..hw {
            for c in 0..4 {
                let sum = at(2 * x, 2 * y, c)
                    + at(2 * x + 1, 2 * y, c)
                    + at(2 * x, 2 * y + 1, c)
                    + at(2 * x + 1, 2 * y + 1, c);
                out.push(((sum + 2) / 4) as u8);
            }
        }
    }
    (hw, hh, out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Frame `i` of a test flight: `w`×`h`, every pixel (i, x, y, 255) (mod 256).
    fn frame(i: usize, w: u32, h: u32) -> Vec<u8> {
        (0..h)
            .flat_map(|y| (0..w).flat_map(move |x| [i as u8, x as u8, y as u8, 255]))
            .collect()
    }

    fn write_frames(dir: &Path, n: usize, w: u32, h: u32) -> Vec<PathBuf> {
        for i in 0..n {
            let png = cbdam_render::encode_png(w, h, &frame(i, w, h)).unwrap();
            std::fs::write(dir.join(format!("frame_{i:05}.png")), png).unwrap();
        }
        frames_in(dir)
    }

    /// A frame of an APNG: its size, its delay (numerator, denominator) and its pixels.
    type ApngFrame = ((u32, u32), (u16, u16), Vec<u8>);

    /// An APNG's play count and frames.
    fn read_apng(path: &Path) -> (u32, Vec<ApngFrame>) {
        let file = std::io::BufReader::new(std::fs::File::open(path).unwrap());
        let mut reader = png::Decoder::new(file).read_info().unwrap();
        let control = reader.info().animation_control.expect("an APNG");
        let mut frames = Vec::new();
        for _ in 0..control.num_frames {
            let mut buf = vec![0; reader.output_buffer_size().unwrap()];
            let info = reader.next_frame(&mut buf).unwrap();
            buf.truncate(info.buffer_size());
            let fc = reader.info().frame_control.unwrap();
            frames.push(((fc.width, fc.height), (fc.delay_num, fc.delay_den), buf));
        }
        (control.num_plays, frames)
    }

    #[test]
    fn a_short_flight_keeps_every_frame_as_it_was() {
        let dir = tempfile::tempdir().unwrap();
        let frames = write_frames(dir.path(), 5, 40, 30);
        assert_eq!(frames.len(), 5);
        let out = dir.path().join("flight.png");
        assert_eq!(
            write_apng(&frames, 30.0, &out).unwrap(),
            (5, (40, 30), 30.0)
        );
        let (plays, read) = read_apng(&out);
        assert_eq!(plays, 0, "loops forever");
        assert_eq!(read.len(), 5);
        for (i, (size, delay, rgba)) in read.into_iter().enumerate() {
            assert_eq!(size, (40, 30));
            assert_eq!(delay, (33, 1000));
            assert_eq!(rgba, frame(i, 40, 30), "frame {i}");
        }
    }

    #[test]
    fn a_long_wide_flight_is_halved_in_size_and_rate() {
        let dir = tempfile::tempdir().unwrap();
        // 61 frames (one past those kept whole) of 964 pixels: halved twice, to 241 × 2.
        let frames = write_frames(dir.path(), APNG_ALL_FRAMES + 1, 964, 9);
        let out = dir.path().join("flight.png");
        assert_eq!(
            write_apng(&frames, 30.0, &out).unwrap(),
            (31, (241, 2), 15.0)
        );
        let (_, read) = read_apng(&out);
        assert_eq!(read.len(), 31);
        for (k, (size, delay, rgba)) in read.into_iter().enumerate() {
            assert_eq!((size, delay), ((241, 2), (67, 1000)));
            // Frame 2k; each pixel the mean of a 4×4 block, rounded up at both halvings:
            // x = 4X + 1.5 → 4X + 2, and so y.
            let px = |x: usize, y: usize| &rgba[4 * (y * 241 + x)..][..4];
            assert_eq!(px(0, 0), [(2 * k) as u8, 2, 2, 255]);
            assert_eq!(px(10, 1), [(2 * k) as u8, 42, 6, 255]);
        }
    }

    #[test]
    fn halvings_bring_frames_to_the_apng_width() {
        for (width, n) in [
            (160, 0),
            (480, 0),
            (481, 1),
            (640, 1),
            (960, 1),
            (1920, 2),
            (3840, 3),
        ] {
            assert_eq!(halvings(width), n, "{width}");
            assert!(width >> n <= APNG_MAX_WIDTH);
        }
    }

    #[test]
    fn frames_of_another_size_or_none_are_refused() {
        let dir = tempfile::tempdir().unwrap();
        let err = write_flight(dir.path(), 30.0, &dir.path().join("v")).unwrap_err();
        assert!(err.to_string().contains("no frame_00000.png"), "{err}");
        write_frames(dir.path(), 2, 8, 8);
        let odd = cbdam_render::encode_png(6, 8, &frame(2, 6, 8)).unwrap();
        std::fs::write(dir.path().join("frame_00002.png"), odd).unwrap();
        let out = dir.path().join("v.png");
        let err = write_apng(&frames_in(dir.path()), 30.0, &out).unwrap_err();
        assert!(
            format!("{err:#}").contains("is 6×8, the first frame 8×8"),
            "{err:#}"
        );
        assert!(!out.exists(), "a failed video leaves nothing");
    }
}
