//! Decode jobs as bytes, for workers that share no memory with the refiner (a page's Web
//! Workers running the same wasm module, which get `postMessage`s).
//!
//! Three messages, each `magic (4) ‖ version (1) ‖ payload ‖ CRC-32 of what precedes (4)`, all
//! integers little-endian:
//! - the **context** (`CBDC`), sent once per worker: the repository head's bytes (from which the
//!   worker builds the decoder, as the refiner's source did), those of the draped colour
//!   repository if any, and the refiner's detail shift and seed;
//! - a **job** (`CBDJ`): whether it decodes ahead, the given parents' nodes, and the steps
//!   (diamond id and its record bytes, synthetic amplitude, cached node, or why its record
//!   could not be read);
//! - its **results** (`CBDR`): per step, the refined node, the decoding error, or nothing (a
//!   parent failed), with the worker's time.
//!
//! A node travels as its refinement only (vertices, cell centres, the nodata mask if any, and
//! the three colour channels when a colour is draped): the receiver rebuilds the children's
//! halves. Reading never panics: a message that is short, has a bad checksum, names a diamond
//! outside the domain, a grid of the wrong size, or results that do not match the job's steps
//! is a [`CodecError`] naming the problem.

use std::borrow::Cow;
use std::sync::Arc;
use std::sync::mpsc::Sender;

use cbdam_codec::CodecError;
use cbdam_codec::colour::{Alignment, ColourRefined};
use cbdam_codec::geometry::{DiamondId, Domain};
use cbdam_codec::hierarchy::{Decoder, Refined};
use cbdam_codec::lifting::MAX_ABS_HEIGHT;
use cbdam_codec::repository::RepositoryHead;

use super::job::{DecodeJob, Done, Source};
use super::node::Node;
use crate::access::Drape;
use crate::spawn::Portable;

const CONTEXT_MAGIC: &[u8; 4] = b"CBDC";
const JOB_MAGIC: &[u8; 4] = b"CBDJ";
const RESULTS_MAGIC: &[u8; 4] = b"CBDR";
const VERSION: u8 = 1;

/// The first bytes of a repository file, at least its head (header, root field, index and
/// checksum table), and the file's length: what a remote source read to open it.
#[derive(Clone, Copy, Debug)]
pub struct HeadBytes<'a> {
    /// The head (the whole file will do).
    pub bytes: &'a [u8],
    /// The whole file's length.
    pub file_len: u64,
}

/// The context message for workers: how to decode (the heads of the elevation repository and
/// of the draped colour one) and the refiner's detail settings.
pub(super) fn encode_context(
    elevation: HeadBytes,
    colour: Option<HeadBytes>,
    shift: u32,
    seed: u64,
) -> Vec<u8> {
    let mut w = Writer::new(CONTEXT_MAGIC);
    w.u32(shift);
    w.u64(seed);
    w.head(elevation);
    w.u8(u8::from(colour.is_some()));
    if let Some(c) = colour {
        w.head(c);
    }
    w.finish()
}

/// A worker's side of the decode seam: the decoder and drape built from a context message, and
/// jobs run from their bytes.
#[derive(Debug)]
pub struct WorkerDecoder {
    decoder: Arc<Decoder>,
    drape: Option<Arc<Drape>>,
    domain: Domain,
    shift: u32,
    seed: u64,
}

impl WorkerDecoder {
    /// Reads a context message ([`super::Refiner::worker_context`]) and builds the decoder.
    pub fn new(context: &[u8]) -> Result<Self, CodecError> {
        let mut r = Reader::open(context, CONTEXT_MAGIC, "decode context")?;
        let shift = r.u32()?;
        let seed = r.u64()?;
        let elevation = r.head()?;
        let colour = match r.u8()? {
            0 => None,
            1 => Some(r.head()?),
            b => return Err(r.bad(format!("colour flag {b}"))),
        };
        r.end()?;
        let head = RepositoryHead::parse(elevation.bytes, elevation.file_len)?;
        let decoder = head.decoder()?;
        let drape = match colour {
            None => None,
            Some(c) => {
                let ch = RepositoryHead::parse(c.bytes, c.file_len)?;
                let alignment =
                    Alignment::new(head.params(), head.georef(), ch.params(), ch.georef())?;
                Some(Arc::new(Drape {
                    decoder: ch.colour_decoder()?,
                    alignment,
                }))
            }
        };
        let domain = head.params().domain.with_detail(shift)?;
        Ok(Self {
            decoder: Arc::new(decoder),
            drape,
            domain,
            shift,
            seed,
        })
    }

    /// Runs a job message ([`crate::spawn::Portable::encode`] of a [`DecodeJob`]) and answers
    /// with its results message. A malformed job is an error (nothing is decoded); a record
    /// that fails to decode is a result, not an error.
    pub fn run(&self, job: &[u8]) -> Result<Vec<u8>, CodecError> {
        let (tx, rx) = std::sync::mpsc::channel();
        let job = decode_job(self, job, tx)?;
        job.run_steps();
        let done: Vec<Done> = rx.try_iter().collect();
        Ok(encode_results(&done))
    }
}

/// A decode job crosses to a worker as `encode_job`'s bytes and comes back through
/// `decode_results` (here rather than in `job.rs`, which knows nothing of the wire).
impl Portable for DecodeJob {
    fn run(self) {
        self.run_steps();
    }

    fn run_until(self, stop: &dyn Fn() -> bool) -> Option<Self> {
        DecodeJob::run_until(self, stop)
    }

    fn encode(&self) -> Vec<u8> {
        encode_job(self)
    }

    fn receive(&self, answer: &[u8]) -> Result<(), CodecError> {
        let done = decode_results(self, answer)?;
        for d in done {
            // The refiner may be gone; then nobody wants the result.
            let _ = self.tx.send(d);
        }
        Ok(())
    }

    fn steps(&self) -> usize {
        self.steps.len()
    }
}

/// A job as a message.
pub(super) fn encode_job(job: &DecodeJob) -> Vec<u8> {
    let mut w = Writer::new(JOB_MAGIC);
    w.u8(u8::from(job.speculative));
    w.u32(job.given.len() as u32);
    for (id, node) in &job.given {
        w.id(*id);
        w.node(sent_refinement(node), node.colour.as_ref());
    }
    w.u32(job.steps.len() as u32);
    for (id, source) in &job.steps {
        w.id(*id);
        match source {
            Source::Cached(node) => {
                w.u8(0);
                w.node(sent_refinement(node), node.colour.as_ref());
            }
            Source::Record(bytes) => {
                w.u8(1);
                w.bytes(bytes);
            }
            // Read (and checked) here: the worker has no map.
            Source::Mapped(record) => match record.bytes() {
                Ok(bytes) => {
                    w.u8(1);
                    w.bytes(bytes);
                }
                Err(e) => w.unreadable(&e),
            },
            Source::Unreadable(e) => w.unreadable(e),
            Source::Synthetic(amp) => {
                w.u8(2);
                w.i32(*amp);
            }
        }
    }
    w.finish()
}

/// A job message read back in a worker, reporting into `tx`. Given parents' nodes carry no
/// children's halves (the worker only gathers from their refinements).
fn decode_job(
    ctx: &WorkerDecoder,
    bytes: &[u8],
    tx: Sender<Done>,
) -> Result<DecodeJob, CodecError> {
    let mut r = Reader::open(bytes, JOB_MAGIC, "decode job")?;
    let n = ctx.domain.n();
    let colour = ctx.drape.is_some();
    let speculative = match r.u8()? {
        0 => false,
        1 => true,
        b => return Err(r.bad(format!("speculative flag {b}"))),
    };
    let given_count = r.count(NODE_MIN_BYTES)?;
    let mut given = Vec::with_capacity(given_count);
    for _ in 0..given_count {
        let id = r.id(&ctx.domain)?;
        let (refined, colour) = r.node(n, colour)?;
        given.push((id, bare_node(n, refined, colour)));
    }
    let step_count = r.count(ID_BYTES + 1)?;
    let mut steps = Vec::with_capacity(step_count);
    for _ in 0..step_count {
        let id = r.id(&ctx.domain)?;
        let source = match r.u8()? {
            0 => {
                let (refined, colour) = r.node(n, colour)?;
                Source::Cached(bare_node(n, refined, colour))
            }
            1 => Source::Record(r.bytes()?.into()),
            2 => {
                let amp = r.i32()?;
                if !(0..=MAX_ABS_HEIGHT).contains(&amp) {
                    return Err(r.bad(format!("synthetic amplitude {amp}")));
                }
                Source::Synthetic(amp)
            }
            3 => Source::Unreadable(r.error()?),
            t => return Err(r.bad(format!("step source {t}"))),
        };
        steps.push((id, source));
    }
    r.end()?;
    Ok(DecodeJob {
        decoder: ctx.decoder.clone(),
        drape: ctx.drape.clone(),
        domain: ctx.domain,
        given,
        shift: ctx.shift,
        seed: ctx.seed,
        steps,
        speculative,
        tx,
        from_message: true,
        keep_refined: true,
    })
}

fn bare_node(n: usize, refined: Refined, colour: Option<ColourRefined>) -> Arc<Node> {
    Arc::new(Node::new(
        n,
        Some(refined),
        colour,
        Default::default(),
        Default::default(),
    ))
}

/// The refinement a message carries for `node`. Nodes keep theirs when the refiner's spawner
/// sends jobs as messages
/// ([`Spawner::sends_jobs_as_messages`](crate::spawn::Spawner::sends_jobs_as_messages)), and a
/// worker's nodes always do.
fn sent_refinement(node: &Node) -> &Refined {
    node.refined().expect(
        "a job sent as a message by a spawner whose sends_jobs_as_messages() is false \
         (its nodes dropped their refinements)",
    )
}

/// A worker's results as a message.
pub(super) fn encode_results(done: &[Done]) -> Vec<u8> {
    let mut w = Writer::new(RESULTS_MAGIC);
    w.u32(done.len() as u32);
    for d in done {
        w.id(d.id);
        match &d.result {
            None => w.u8(0),
            Some(Ok(node)) => {
                w.u8(1);
                w.node(sent_refinement(node), node.colour.as_ref());
            }
            Some(Err(e)) => {
                w.u8(2);
                w.error(e);
            }
        }
        match d.secs {
            None => w.u8(0),
            Some(s) => {
                w.u8(1);
                w.f64(s);
            }
        }
    }
    w.finish()
}

/// The results of `job` read back from a worker's answer: one per step, in order, with the
/// nodes' children's halves rebuilt.
pub(super) fn decode_results(job: &DecodeJob, bytes: &[u8]) -> Result<Vec<Done>, CodecError> {
    let mut r = Reader::open(bytes, RESULTS_MAGIC, "decode results")?;
    let count = r.count(ID_BYTES + 2)?;
    if count != job.steps.len() {
        return Err(r.bad(format!("{count} results for {} steps", job.steps.len())));
    }
    let n = job.domain.n();
    let mut done = Vec::with_capacity(count);
    for (i, (step, _)) in job.steps.iter().enumerate() {
        let id = r.id(&job.domain)?;
        if id != *step {
            return Err(r.bad(format!("result {i} is for {id}, the step is {step}")));
        }
        let result = match r.u8()? {
            0 => None,
            1 => {
                let (refined, colour) = r.node(n, job.drape.is_some())?;
                Some(Ok(job.node(id, refined, colour)))
            }
            2 => Some(Err(r.error()?)),
            t => return Err(r.bad(format!("result tag {t}"))),
        };
        let secs = match r.u8()? {
            0 => None,
            1 => {
                let s = r.f64()?;
                if !(s.is_finite() && s >= 0.0) {
                    return Err(r.bad(format!("decode time {s} s")));
                }
                Some(s)
            }
            b => return Err(r.bad(format!("time flag {b}"))),
        };
        done.push(Done {
            id,
            result,
            secs,
            // A worker's answer carries its wall time only.
            cpu_secs: None,
            speculative: job.speculative,
            last: i + 1 == count,
        });
    }
    r.end()?;
    Ok(done)
}

fn error_parts(e: &CodecError) -> (u8, String) {
    match e {
        CodecError::Io(e) => (0, e.to_string()),
        CodecError::Corrupt(m) => (1, m.to_string()),
        CodecError::Truncated(m) => (2, m.to_string()),
        CodecError::Unsupported(m) => (3, m.to_string()),
        CodecError::InvalidParameter(m) => (4, m.to_string()),
        CodecError::LimitExceeded(m) => (5, m.to_string()),
    }
}

fn error_from_parts(kind: u8, m: String) -> Option<CodecError> {
    let m: Cow<'static, str> = m.into();
    Some(match kind {
        0 => CodecError::Io(std::io::Error::other(m.into_owned())),
        1 => CodecError::Corrupt(m),
        2 => CodecError::Truncated(m),
        3 => CodecError::Unsupported(m),
        4 => CodecError::InvalidParameter(m),
        5 => CodecError::LimitExceeded(m),
        _ => return None,
    })
}

/// Bytes of a diamond id: level, face, x, y.
const ID_BYTES: usize = 10;
/// Fewest bytes of an id and a node: an id, `N`, one vertex, no cells, two flags.
const NODE_MIN_BYTES: usize = ID_BYTES + 4 + 4 + 2;

struct Writer(Vec<u8>);

impl Writer {
    fn new(magic: &[u8; 4]) -> Self {
        let mut b = Vec::with_capacity(1 << 12);
        b.extend_from_slice(magic);
        b.push(VERSION);
        Self(b)
    }
    fn u8(&mut self, v: u8) {
        self.0.push(v);
    }
    fn u32(&mut self, v: u32) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn u64(&mut self, v: u64) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn i32(&mut self, v: i32) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    fn f64(&mut self, v: f64) {
        self.0.extend_from_slice(&v.to_le_bytes());
    }
    /// A step whose record could not be read: why (as a result's error is written).
    fn unreadable(&mut self, e: &CodecError) {
        self.u8(3);
        self.error(e);
    }
    /// An error: its kind and message.
    fn error(&mut self, e: &CodecError) {
        let (kind, message) = error_parts(e);
        self.u8(kind);
        self.bytes(message.as_bytes());
    }
    fn bytes(&mut self, b: &[u8]) {
        self.u32(b.len() as u32);
        self.0.extend_from_slice(b);
    }
    fn head(&mut self, h: HeadBytes) {
        self.u64(h.file_len);
        self.bytes(h.bytes);
    }
    fn id(&mut self, id: DiamondId) {
        self.u8(id.level);
        self.u8(id.face);
        self.u32(id.x);
        self.u32(id.y);
    }
    fn refined(&mut self, r: &Refined) {
        let n = r.n();
        self.u32(n as u32);
        self.0.reserve(4 * (n * n + (n - 1) * (n - 1)));
        for j in 0..n {
            for i in 0..n {
                self.i32(r.vertex(i, j));
            }
        }
        for j in 0..n - 1 {
            for i in 0..n - 1 {
                self.i32(r.cell(i, j));
            }
        }
        match r.validity() {
            None => self.u8(0),
            Some(v) => {
                self.u8(1);
                self.0.extend(v.iter().map(|&b| u8::from(b)));
            }
        }
    }
    fn node(&mut self, refined: &Refined, colour: Option<&ColourRefined>) {
        self.refined(refined);
        match colour {
            None => self.u8(0),
            Some(c) => {
                self.u8(1);
                for channel in c {
                    self.refined(channel);
                }
            }
        }
    }
    fn finish(mut self) -> Vec<u8> {
        let crc = crc32fast::hash(&self.0);
        self.u32(crc);
        self.0
    }
}

struct Reader<'a> {
    b: &'a [u8],
    at: usize,
    what: &'static str,
}

impl<'a> Reader<'a> {
    /// Checks length, checksum, magic and version; the reader then stands after the version.
    fn open(bytes: &'a [u8], magic: &[u8; 4], what: &'static str) -> Result<Self, CodecError> {
        let Some((body, crc)) = bytes.split_last_chunk::<4>() else {
            return Err(CodecError::truncated(format!(
                "{what}: {} bytes, not even a checksum",
                bytes.len()
            )));
        };
        if body.len() < 5 {
            return Err(CodecError::truncated(format!(
                "{what}: {} bytes, shorter than its magic and version",
                bytes.len()
            )));
        }
        if &body[..4] != magic {
            return Err(CodecError::corrupt(format!(
                "{what}: wrong magic {:?} (expected {:?})",
                String::from_utf8_lossy(&body[..4]),
                String::from_utf8_lossy(magic)
            )));
        }
        if body[4] != VERSION {
            return Err(CodecError::unsupported(format!(
                "{what}: version {} (this build reads {VERSION})",
                body[4]
            )));
        }
        if crc32fast::hash(body) != u32::from_le_bytes(*crc) {
            return Err(CodecError::corrupt(format!(
                "{what}: checksum mismatch ({} bytes)",
                bytes.len()
            )));
        }
        Ok(Self {
            b: body,
            at: 5,
            what,
        })
    }
    fn bad(&self, problem: String) -> CodecError {
        CodecError::corrupt(format!("{}: {problem} at byte {}", self.what, self.at))
    }
    fn take(&mut self, len: usize) -> Result<&'a [u8], CodecError> {
        if len > self.b.len() - self.at {
            return Err(CodecError::truncated(format!(
                "{}: {len} bytes wanted at byte {}, {} left",
                self.what,
                self.at,
                self.b.len() - self.at
            )));
        }
        let s = &self.b[self.at..self.at + len];
        self.at += len;
        Ok(s)
    }
    fn array<const L: usize>(&mut self) -> Result<[u8; L], CodecError> {
        let s = self.take(L)?;
        Ok(s.try_into().expect("took L bytes"))
    }
    fn u8(&mut self) -> Result<u8, CodecError> {
        Ok(self.array::<1>()?[0])
    }
    fn u32(&mut self) -> Result<u32, CodecError> {
        Ok(u32::from_le_bytes(self.array()?))
    }
    fn u64(&mut self) -> Result<u64, CodecError> {
        Ok(u64::from_le_bytes(self.array()?))
    }
    fn i32(&mut self) -> Result<i32, CodecError> {
        Ok(i32::from_le_bytes(self.array()?))
    }
    fn f64(&mut self) -> Result<f64, CodecError> {
        Ok(f64::from_le_bytes(self.array()?))
    }
    /// An error written by `Writer::error`.
    fn error(&mut self) -> Result<CodecError, CodecError> {
        let kind = self.u8()?;
        let message = String::from_utf8(self.bytes()?.to_vec())
            .map_err(|_| self.bad("an error message that is not UTF-8".into()))?;
        error_from_parts(kind, message).ok_or_else(|| self.bad(format!("error kind {kind}")))
    }
    /// A length-prefixed byte string.
    fn bytes(&mut self) -> Result<&'a [u8], CodecError> {
        let len = self.u32()? as usize;
        self.take(len)
    }
    /// An element count, checked against what is left (each element takes at least
    /// `min_bytes`), so nothing is allocated for a count the message cannot hold.
    fn count(&mut self, min_bytes: usize) -> Result<usize, CodecError> {
        let c = self.u32()? as usize;
        if c.saturating_mul(min_bytes) > self.b.len() - self.at {
            return Err(CodecError::truncated(format!(
                "{}: {c} elements announced at byte {}, {} bytes left",
                self.what,
                self.at,
                self.b.len() - self.at
            )));
        }
        Ok(c)
    }
    fn head(&mut self) -> Result<HeadBytes<'a>, CodecError> {
        let file_len = self.u64()?;
        let bytes = self.bytes()?;
        Ok(HeadBytes { bytes, file_len })
    }
    fn id(&mut self, domain: &Domain) -> Result<DiamondId, CodecError> {
        let level = self.u8()?;
        let face = self.u8()?;
        let x = self.u32()?;
        let y = self.u32()?;
        let id = DiamondId { level, face, x, y };
        if !domain.contains(id) {
            return Err(self.bad(format!("diamond {id} outside the domain")));
        }
        Ok(id)
    }
    fn heights(&mut self, count: usize) -> Result<Vec<i32>, CodecError> {
        let raw = self.take(4 * count)?;
        let mut out = Vec::with_capacity(count);
        for c in raw.chunks_exact(4) {
            let v = i32::from_le_bytes(c.try_into().expect("4 bytes"));
            if v.unsigned_abs() > MAX_ABS_HEIGHT as u32 {
                return Err(self.bad(format!("height {v} beyond ±{MAX_ABS_HEIGHT}")));
            }
            out.push(v);
        }
        Ok(out)
    }
    fn refined(&mut self, n: usize) -> Result<Refined, CodecError> {
        let got = self.u32()? as usize;
        if got != n {
            return Err(self.bad(format!("a {got}-point grid side in a domain of N = {n}")));
        }
        let vertices = self.heights(n * n)?;
        let cells = self.heights((n - 1) * (n - 1))?;
        let valid = match self.u8()? {
            0 => None,
            1 => {
                let side = 2 * n - 1;
                let raw = self.take(side * side)?;
                if let Some(b) = raw.iter().find(|&&b| b > 1) {
                    return Err(self.bad(format!("validity byte {b}")));
                }
                Some(raw.iter().map(|&b| b == 1).collect())
            }
            b => return Err(self.bad(format!("validity flag {b}"))),
        };
        Ok(Refined::from_parts(n, &vertices, &cells).with_validity(valid))
    }
    fn node(
        &mut self,
        n: usize,
        colour: bool,
    ) -> Result<(Refined, Option<ColourRefined>), CodecError> {
        let refined = self.refined(n)?;
        let c = match (self.u8()?, colour) {
            (0, false) => None,
            (1, true) => Some([self.refined(n)?, self.refined(n)?, self.refined(n)?]),
            (0, true) => return Err(self.bad("a node without the draped colour".into())),
            (1, false) => return Err(self.bad("a colour node without a drape".into())),
            (b, _) => return Err(self.bad(format!("colour flag {b}"))),
        };
        Ok((refined, c))
    }
    fn end(&self) -> Result<(), CodecError> {
        if self.at != self.b.len() {
            return Err(self.bad(format!("{} bytes left over", self.b.len() - self.at)));
        }
        Ok(())
    }
}
