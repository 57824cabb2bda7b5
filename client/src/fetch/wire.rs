//! What goes over the wire, portable to every transport: batch request bodies and the frames
//! of their answers, range requests and the spans they cover, the head read by ranges, and the
//! checks every record passes before it is handed over.

use super::schedule::record_range;
use super::{RemoteError, http_error};
use cbdam_codec::CodecError;
use cbdam_codec::geometry::DiamondId;
use cbdam_codec::repository::batch::Entry;
use cbdam_codec::repository::{RepositoryHead, batch};
use std::sync::Arc;

/// Splits the body of a batch request for `ids` into records: the framing is the codec's
/// ([`cbdam_codec::repository::batch`]); every id must be answered, in order, with a record.
pub fn parse_frames(body: &[u8], ids: &[DiamondId]) -> Result<Vec<(DiamondId, Vec<u8>)>, String> {
    let entries = batch::parse(body).map_err(|e| e.to_string())?;
    if entries.len() != ids.len() {
        return Err(format!(
            "asked for {} records, response holds {}",
            ids.len(),
            entries.len()
        ));
    }
    ids.iter()
        .zip(entries)
        .map(|(&id, entry)| match entry {
            Entry::Record(bytes) => Ok((id, bytes.to_vec())),
            Entry::NotStored => Err(format!(
                "server says {id} is not stored, the head says it is"
            )),
        })
        .collect()
}

/// Checks the status of a response to `Range: bytes=start-(end-1)`: it must be 206 (Partial
/// Content); anything else means the server ignored the range (and would send the whole file).
pub(super) fn expect_partial(range: &std::ops::Range<u64>, status: u16) -> Result<(), String> {
    if status == 206 {
        return Ok(());
    }
    Err(format!(
        "asked for bytes {}..{}, got HTTP {status} (does the server honour Range requests?)",
        range.start, range.end,
    ))
}

/// Checks the body of a 206 response to the request for `range`: `content_range` (the header's
/// value) must carry the file's total length; a range running past the end of the file gets
/// the bytes up to the end (what a server answers), any other body length is an error. Returns
/// the total.
pub(super) fn range_total(
    range: &std::ops::Range<u64>,
    content_range: Option<&str>,
    body_len: usize,
) -> Result<u64, String> {
    let total = content_range
        .and_then(|v| v.rsplit_once('/'))
        .and_then(|(_, total)| total.parse::<u64>().ok())
        .ok_or("206 response without a Content-Range total")?;
    let end = range.end.min(total.max(range.start));
    if body_len as u64 != end - range.start {
        return Err(format!(
            "asked for {} bytes, got {body_len}",
            end - range.start
        ));
    }
    Ok(total)
}

/// Reads the repository head of the file at `url` with `get_range` (a transport's range GET,
/// returning the body and the file's total length); also returns the head's bytes.
pub(super) async fn fetch_head_with<F, Fut>(
    url: &str,
    get_range: F,
) -> Result<(RepositoryHead, Vec<u8>), RemoteError>
where
    F: Fn(std::ops::Range<u64>) -> Fut,
    Fut: std::future::Future<Output = Result<(Vec<u8>, u64), String>>,
{
    use cbdam_codec::repository::{HEADER_FETCH_LEN, header_len, required_head_len};
    // A version-3 header is usually shorter than HEADER_FETCH_LEN, and so can be the whole
    // file: a server answers a range past the end with what there is. A long CRS definition
    // makes it longer: then a second request fetches the rest.
    let (mut header, file_len) = get_range(0..HEADER_FETCH_LEN as u64)
        .await
        .map_err(|e| http_error(url, e))?;
    let repo_error = |source| RemoteError::Repository {
        url: url.to_owned(),
        source,
    };
    let len = header_len(&header).map_err(repo_error)?;
    if len > header.len() && len as u64 <= file_len {
        header = get_range(0..len as u64)
            .await
            .map_err(|e| http_error(url, e))?
            .0;
    }
    let head_len = required_head_len(&header).map_err(repo_error)?;
    if head_len > file_len {
        return Err(repo_error(CodecError::truncated(format!(
            "the head is {head_len} bytes, the file {file_len}"
        ))));
    }
    let (head, _) = get_range(0..head_len)
        .await
        .map_err(|e| http_error(url, e))?;
    let parsed = RepositoryHead::parse(&head, file_len).map_err(repo_error)?;
    Ok((parsed, head))
}

/// The byte span of one range request for `ids`' records (chosen close together by
/// [`next_batch`]) and each record's range in the file.
pub(super) fn batch_span(
    head: &RepositoryHead,
    ids: &[DiamondId],
) -> (std::ops::Range<u64>, Vec<std::ops::Range<u64>>) {
    let ranges: Vec<_> = ids.iter().map(|&id| record_range(head, id)).collect();
    let lo = ranges
        .iter()
        .map(|r| r.start)
        .min()
        .expect("non-empty batch");
    let hi = ranges.iter().map(|r| r.end).max().expect("non-empty batch");
    (lo..hi, ranges)
}

/// Cuts the body of the range request for `span` into `ids`' records; `total` is the file
/// length the server reported.
pub(super) fn split_span(
    head: &RepositoryHead,
    ids: &[DiamondId],
    span: std::ops::Range<u64>,
    ranges: Vec<std::ops::Range<u64>>,
    body: &[u8],
    total: u64,
) -> Result<Vec<(DiamondId, Vec<u8>)>, String> {
    if total != head.file_len() {
        return Err(format!(
            "the file is now {total} bytes, the head says {}: it changed on the server",
            head.file_len()
        ));
    }
    // The head's records lie inside the file, so only a server that cut the range short gives
    // fewer bytes; the slicing below needs all of them.
    if body.len() as u64 != span.end - span.start {
        return Err(format!(
            "asked for {} bytes, got {}",
            span.end - span.start,
            body.len()
        ));
    }
    let lo = span.start;
    Ok(ids
        .iter()
        .zip(ranges)
        .map(|(&id, r)| {
            (
                id,
                body[(r.start - lo) as usize..(r.end - lo) as usize].to_vec(),
            )
        })
        .collect())
}

/// Records that passed their checks.
pub(super) type Checked = Vec<(DiamondId, Arc<[u8]>)>;

/// `records` checked against the head: those that pass, and the ids of those that fail (to be
/// retried).
pub(super) fn check_records(
    head: &RepositoryHead,
    records: Vec<(DiamondId, Vec<u8>)>,
) -> (Checked, Vec<DiamondId>) {
    let mut passed = Vec::with_capacity(records.len());
    let mut failed = Vec::new();
    for (id, bytes) in records {
        let i = head.position(id).expect("stored");
        match head.check_record(i, &bytes) {
            Ok(()) => passed.push((id, Arc::from(bytes))),
            Err(e) => {
                tracing::warn!("record {id} rejected: {e}");
                failed.push(id);
            }
        }
    }
    (passed, failed)
}

/// The JSON body of a batch request (`POST …/diamonds`) for `ids` with their `priorities`
/// (screen errors; the server answers the highest first, see [`batch::answer_order`]), as
/// [`wire_priorities`] writes them.
pub(super) fn batch_request_body(ids: &[DiamondId], priorities: &[f32]) -> String {
    let names: Vec<String> = ids.iter().map(ToString::to_string).collect();
    serde_json::json!({ "ids": names, "priorities": wire_priorities(priorities) }).to_string()
}

/// Priorities as a batch request carries them: three significant digits (about 4 bytes of
/// JSON each instead of 9: the order, not the value, is what the server needs, and rounding
/// keeps a sorted list sorted), non-finite ones as 0 (JSON has no infinities).
pub(super) fn wire_priorities(priorities: &[f32]) -> Vec<f64> {
    priorities
        .iter()
        .map(|&p| {
            if !p.is_finite() || p == 0.0 {
                return 0.0;
            }
            let p = f64::from(p);
            let scale = 10f64.powi(2 - p.abs().log10().floor() as i32);
            (p * scale).round() / scale
        })
        .collect()
}

/// The ids of a batch request in the order the server answers them.
pub(super) fn answer_ids(ids: &[DiamondId], priorities: &[f32]) -> Vec<DiamondId> {
    // As the server reads them: f32.
    let read: Vec<f32> = wire_priorities(priorities)
        .into_iter()
        .map(|p| p as f32)
        .collect();
    batch::answer_order(&read)
        .into_iter()
        .map(|k| ids[k])
        .collect()
}
