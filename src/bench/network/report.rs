//! The Markdown tables, the targets against what was measured, and the JSON of
//! `cbdam bench network`.

use std::fmt::Write as _;

use anyhow::Result;
use serde_json::json;

use super::measure::{Measured, Route};

fn mb(bytes: u64) -> String {
    format!("{:.2}", bytes as f64 / 1e6)
}

/// "profile", "server" of a run; the local file has no link and no server.
fn labels(m: &Measured) -> (String, String) {
    match &m.route {
        Route::Local => ("local file".into(), "—".into()),
        Route::Remote {
            profile, server, ..
        } => (profile.clone(), server.name().into()),
    }
}

/// The local run of the same flight, if any.
fn local_of<'a>(runs: &'a [Measured], m: &Measured) -> Option<&'a Measured> {
    runs.iter()
        .find(|r| r.route == Route::Local && r.flight == m.flight)
}

/// Whether `m`'s final cut is the local run's: `None` when either did not converge (a cut
/// still refining is not expected to match) or there is no local run.
pub fn same_cut_as_local(runs: &[Measured], m: &Measured) -> Option<bool> {
    let local = local_of(runs, m)?;
    (m.converged() && local.converged()).then(|| m.final_cut == local.final_cut)
}

fn ratio(m: &Measured) -> f64 {
    m.bytes_fetched as f64 / m.bytes_used.max(1) as f64
}

fn seconds(s: Option<f64>) -> String {
    s.map_or_else(|| "not met".into(), |s| format!("{s:.2}"))
}

/// The main table: one row per run.
pub fn table(runs: &[Measured], budget_ms: f64) -> Result<String> {
    let mut out = String::new();
    out += "| profile | server | flight | MB fetched | MB used by the cuts | fetched / used \
            | MB over the link | requests (/s) | Range requests (/s) | flight frames at target \
            | camera stop → target (s) | converged | frames over budget: wall (max ms) \
            | frames over budget: CPU | final cut = local |\n\
            |---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---|---:|---:|---|\n";
    for m in runs {
        let (profile, server) = labels(m);
        let wall = m.wall_s().max(1e-9);
        let (link, requests, ranges) = match &m.wire {
            Some(w) => {
                let all = w.server_batches + w.server_ranges + w.server_other;
                (
                    mb(w.link_bytes_down),
                    format!("{all} ({:.1})", all as f64 / wall),
                    format!("{} ({:.1})", w.server_ranges, w.server_ranges as f64 / wall),
                )
            }
            None => ("—".into(), "—".into(), "—".into()),
        };
        let same = match (&m.route, same_cut_as_local(runs, m)) {
            (Route::Local, _) => "—".to_string(),
            (_, Some(true)) => "yes".into(),
            (_, Some(false)) => "**no**".into(),
            (_, None) => "not converged".into(),
        };
        writeln!(
            out,
            "| {profile} | {server} | {} | {} | {} | {:.2}× | {link} | {requests} | {ranges} \
             | {} of {} | {} | {} | {} ({:.1}) | {} | {same} |",
            m.flight,
            mb(m.bytes_fetched),
            mb(m.bytes_used),
            ratio(m),
            m.flight_frames_at_target(),
            m.flight_frames,
            seconds(m.stop_to_target_s()),
            if m.converged() { "yes" } else { "no" },
            m.frames_over_budget(budget_ms),
            m.max_refine_ms(),
            m.frames_over_budget_cpu(budget_ms),
        )?;
    }
    Ok(out)
}

/// What the remote runs received and no cut used, the lower bound of the time to converge
/// after the camera stops, and the times to 1, 2 and 4 px.
pub fn received_table(runs: &[Measured]) -> Result<String> {
    let mut out = String::new();
    out += "| profile | server | flight | MB received | received again (MB) | after the last frame (MB) | unused, prefetched (MB) \
            | unused, wanted by the cut (MB) | unused, came after withdrawal (MB) \
            | final cut (MB) | final cut lacked at stop (MB) | lower bound (s) \
            | any policy's bound (s) | stop → 1 px (s) | → 2 px (s) | → 4 px (s) |\n\
            |---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n";
    for m in runs {
        let Some(r) = &m.received else { continue };
        let (profile, server) = labels(m);
        writeln!(
            out,
            "| {profile} | {server} | {} | {} | {} | {} | {} | {} | {} | {} | {} | {:.2} | {:.2} \
             | {} | {} | {} |",
            m.flight,
            mb(r.bytes),
            mb(r.repeated),
            mb(r.after_last_frame),
            mb(r.prefetch_unused),
            mb(r.other_unused),
            mb(r.unused_after_withdrawal),
            mb(r.final_bytes),
            mb(r.final_missing_at_stop),
            r.lower_bound_s,
            r.any_policy_bound_s,
            seconds(m.stop_to_px_s(1.0)),
            seconds(m.stop_to_px_s(2.0)),
            seconds(m.stop_to_px_s(4.0)),
        )?;
    }
    Ok(out)
}

/// The requests as the client counted them beside the server's count, and the link's side.
pub fn wire_table(runs: &[Measured]) -> Result<String> {
    let mut out = String::new();
    out += "| profile | server | flight | client requests | cancelled (records re-queued) | failed \
            | server: batch POSTs | server: batches aborted (MB unsent) | server: Range GETs \
            | server: other | connections | resets | MB up |\n\
            |---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n";
    for m in runs {
        let Some(w) = &m.wire else { continue };
        let (profile, server) = labels(m);
        writeln!(
            out,
            "| {profile} | {server} | {} | {} | {} ({}) | {} | {} | {} ({}) | {} | {} | {} | {} | {} |",
            m.flight,
            w.client_requests,
            w.client_cancelled,
            w.client_requeued,
            w.client_errors,
            w.server_batches,
            w.server_aborted,
            mb(w.server_unsent_bytes),
            w.server_ranges,
            w.server_other,
            w.connections,
            w.resets,
            mb(w.link_bytes_up),
        )?;
    }
    Ok(out)
}

/// The targets (issue 21) against the runs.
pub fn targets(runs: &[Measured]) -> Result<String> {
    let mut out = String::new();
    let remote: Vec<&Measured> = runs.iter().filter(|m| m.wire.is_some()).collect();
    if !remote.is_empty() {
        let met = remote.iter().filter(|m| ratio(m) <= 1.2).count();
        let worst = remote
            .iter()
            .max_by(|a, b| ratio(a).total_cmp(&ratio(b)))
            .expect("not empty");
        let (p, s) = labels(worst);
        writeln!(
            out,
            "- Bytes fetched ≤ 1.2× the bytes of the records the cuts used: met by {met} of {} \
             runs; worst {:.2}× ({p}, {s}, {}).",
            remote.len(),
            ratio(worst),
            worst.flight
        )?;
    }
    for (profile, limit) in [("dsl10", 2.0), ("adsl", 10.0)] {
        let of: Vec<&Measured> = remote
            .iter()
            .copied()
            .filter(|m| matches!(&m.route, Route::Remote { profile: p, .. } if p == profile))
            .collect();
        if of.is_empty() {
            continue;
        }
        let list: Vec<String> = of
            .iter()
            .map(|m| {
                let (_, s) = labels(m);
                format!("{} / {s}: {}", m.flight, seconds(m.stop_to_target_s()))
            })
            .collect();
        let met = of
            .iter()
            .filter(|m| m.stop_to_target_s().is_some_and(|s| s <= limit))
            .count();
        writeln!(
            out,
            "- `{profile}`: pixel target within {limit} s of the camera stopping: met by {met} of \
             {} runs ({}).",
            of.len(),
            list.join("; ")
        )?;
    }
    let local: Vec<&Measured> = runs.iter().filter(|m| m.route == Route::Local).collect();
    if !local.is_empty() {
        let list: Vec<String> = local
            .iter()
            .map(|m| format!("{}: {}", m.flight, seconds(m.stop_to_target_s())))
            .collect();
        let met = local
            .iter()
            .filter(|m| m.stop_to_target_s().is_some_and(|s| s <= 0.5))
            .count();
        writeln!(
            out,
            "- Local file: pixel target within 0.5 s of the camera stopping: met by {met} of {} \
             ({}).",
            local.len(),
            list.join("; ")
        )?;
    }
    Ok(out)
}

/// Every run's figures, machine-readable.
pub fn json(all: &[Measured], budget_ms: f64) -> serde_json::Value {
    let runs: Vec<serde_json::Value> = all
        .iter()
        .map(|m| {
            let (profile, server) = match &m.route {
                Route::Local => ("local".to_string(), None),
                Route::Remote {
                    profile, server, ..
                } => (profile.clone(), Some(server.slug())),
            };
            json!({
                "profile": profile,
                "server": server,
                "link": match &m.route {
                    Route::Local => None,
                    Route::Remote { link, .. } => Some(link.to_string()),
                },
                "flight": m.flight,
                "flight_frames": m.flight_frames,
                "frames": m.frames.len(),
                "wall_s": m.wall_s(),
                "bytes_fetched": m.bytes_fetched,
                "bytes_used": m.bytes_used,
                "records_used": m.records_used,
                "flight_frames_at_target": m.flight_frames_at_target(),
                "stop_to_target_s": m.stop_to_target_s(),
                "stop_to_2px_s": m.stop_to_px_s(2.0),
                "stop_to_4px_s": m.stop_to_px_s(4.0),
                "received": m.received.map(|r| json!({
                    "record_bytes": r.bytes,
                    "repeated_record_bytes": r.repeated,
                    "after_last_frame_bytes": r.after_last_frame,
                    "prefetch_unused_bytes": r.prefetch_unused,
                    "cut_wanted_unused_bytes": r.other_unused,
                    "unused_after_withdrawal_bytes": r.unused_after_withdrawal,
                    "final_cut_bytes": r.final_bytes,
                    "any_policy_bound_s": r.any_policy_bound_s,
                    "final_cut_missing_at_stop_bytes": r.final_missing_at_stop,
                    "lower_bound_s": r.lower_bound_s,
                })),
                "converged": m.converged(),
                "frames_over_budget": m.frames_over_budget(budget_ms),
                "max_refine_ms": m.max_refine_ms(),
                "frames_over_budget_cpu": m.frames_over_budget_cpu(budget_ms),
                "final_cut_diamonds": m.final_cut.len(),
                "final_cut_same_as_local": same_cut_as_local(all, m),
                "wire": m.wire.map(|w| json!({
                    "client_requests": w.client_requests,
                    "client_cancelled": w.client_cancelled,
                    "client_in_flight_at_end": w.client_in_flight,
                    "client_errors": w.client_errors,
                    "client_requeued": w.client_requeued,
                    "server_batches_aborted": w.server_aborted,
                    "server_batch_bytes_unsent": w.server_unsent_bytes,
                    "server_batch_requests": w.server_batches,
                    "server_range_requests": w.server_ranges,
                    "server_other_requests": w.server_other,
                    "link_bytes_down": w.link_bytes_down,
                    "link_bytes_up": w.link_bytes_up,
                    "connections": w.connections,
                    "resets": w.resets,
                })),
                "csv": m.csv.file_name().map(|f| f.to_string_lossy().into_owned()),
            })
        })
        .collect();
    json!({ "runs": runs })
}
