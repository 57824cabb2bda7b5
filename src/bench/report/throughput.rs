//! The report's throughput table: every dataset at every ε, our coders' encode and decode on
//! one core and on every core beside the peers' (single-threaded) encode and decode.

use std::fmt::Write as _;

use anyhow::Result;

use super::peers::PeerRow;
use super::{Dataset, codecs, file_safe, find, table_head};

/// `## Throughput: one core and every core`, all datasets in one table.
pub(super) fn section(md: &mut String, datasets: &[Dataset], peer_rows: &[PeerRow]) -> Result<()> {
    let all_rows: Vec<&PeerRow> = peer_rows.iter().collect();
    let cs = codecs(&all_rows);
    let threads = datasets
        .iter()
        .flat_map(|d| d.first())
        .find_map(|(_, m)| m.all_cores.map(|a| a.threads))
        .unwrap_or(1);
    writeln!(md, "## Throughput: one core and every core\n")?;
    writeln!(
        md,
        "M samples/s of wall-clock time (medians). cbdam: *encode* is the encoder alone on \
         the integer grid, *decode* every record and every diamond of the hierarchy, on one \
         thread / on {threads} threads (all cores). Peers: encode / decode of the whole raster, \
         single-threaded.\n"
    )?;
    let mut head = "| dataset | ε (m) |".to_string();
    let mut align = "|---|---:|".to_string();
    for s in datasets.first().map_or(&[][..], |d| &d.ours[..]) {
        let c = s.coder.name();
        head += &format!(" cbdam {c} encode 1 / {threads} | cbdam {c} decode 1 / {threads} |");
        align += "---:|---:|";
    }
    table_head(md, &head, &align, &cs)?;
    for d in datasets {
        let rows: Vec<&PeerRow> = peer_rows
            .iter()
            .filter(|r| r.dem == file_safe(&d.name))
            .collect();
        for (i, (e, _)) in d.first().iter().enumerate() {
            write!(md, "| {} | {e} |", d.name)?;
            for s in &d.ours {
                let m = &s.points[i].1;
                let (enc, dec) = m.all_cores.map_or((f64::NAN, f64::NAN), |a| {
                    (m.msps(a.encode), m.msps(a.decode))
                });
                write!(
                    md,
                    " {:.2} / {enc:.2} | {:.2} / {dec:.2} |",
                    m.msps(m.encode),
                    m.msps(m.decode)
                )?;
            }
            for c in &cs {
                let cell = match find(&rows, c, *e).map(|r| &r.result) {
                    Some(Ok(p)) => format!("{:.1} / {:.1}", p.enc_msps, p.dec_msps),
                    Some(Err(_)) => "–".into(),
                    None => String::new(),
                };
                write!(md, " {cell} |")?;
            }
            md.push('\n');
        }
    }
    md.push('\n');
    Ok(())
}
