//! Peer codecs, measured by `bench/peers.py` in a private Python venv during the same run.
//!
//! Everything here degrades to a message: no Python, no venv module, pip failing (offline) or
//! the harness failing leaves the report without peers, never without our own figures.

use std::io::Write as _;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};

use anyhow::{Context, Result, bail};
use cbdam_codec::samples::{Dem, detect_quantum};
use serde_json::Value;

/// One peer measurement (or a skipped point, with the reason).
#[derive(Clone, Debug)]
pub struct PeerRow {
    pub codec: String,
    pub dem: String,
    /// `None` for lossless references.
    pub eps: Option<f64>,
    pub result: Result<PeerPoint, String>,
}

#[derive(Clone, Debug)]
pub struct PeerPoint {
    pub bps: f64,
    pub max_err: f64,
    pub rms_err: f64,
    pub enc_msps: f64,
    pub dec_msps: f64,
    pub bound_ok: bool,
    pub note: String,
}

/// What the harness reported: package versions and rows.
pub struct Peers {
    pub versions: String,
    pub rows: Vec<PeerRow>,
}

fn harness_dir() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("bench")
}

fn default_venv() -> Option<PathBuf> {
    std::env::var_os("HOME").map(|h| PathBuf::from(h).join(".cache/cbdam-bench-venv"))
}

fn run_quiet(cmd: &mut Command) -> Result<()> {
    let o = cmd
        .stdin(Stdio::null())
        .output()
        .with_context(|| format!("starting {cmd:?}"))?;
    if !o.status.success() {
        let err = String::from_utf8_lossy(&o.stderr);
        let tail: Vec<&str> = err.lines().rev().take(5).collect();
        bail!(
            "{cmd:?} failed ({}): {}",
            o.status,
            tail.into_iter().rev().collect::<Vec<_>>().join(" / ")
        );
    }
    Ok(())
}

/// The venv's python with `bench/requirements.txt` installed, creating or updating it as
/// needed. A copy of the requirements inside the venv records what was installed, so a second
/// report does not run pip again.
fn prepare_venv(venv: &Path) -> Result<PathBuf> {
    let python = venv.join("bin/python");
    if !python.exists() {
        eprintln!("peers: creating a Python venv in {}", venv.display());
        run_quiet(Command::new("python3").arg("-m").arg("venv").arg(venv))?;
    }
    let req = harness_dir().join("requirements.txt");
    let wanted = std::fs::read_to_string(&req).with_context(|| format!("{}", req.display()))?;
    let stamp = venv.join("cbdam-requirements.txt");
    if std::fs::read_to_string(&stamp).ok().as_deref() != Some(wanted.as_str()) {
        eprintln!("peers: pip install -r {}", req.display());
        run_quiet(
            Command::new(&python)
                .args(["-m", "pip", "install", "--quiet", "-r"])
                .arg(&req),
        )?;
        std::fs::write(&stamp, &wanted)?;
    }
    Ok(python)
}

fn parse_row(v: &Value) -> Option<PeerRow> {
    let s = |k: &str| v.get(k).and_then(Value::as_str).map(str::to_string);
    let f = |k: &str| v.get(k).and_then(Value::as_f64);
    let result = match s("skipped") {
        Some(why) => Err(why),
        None => Ok(PeerPoint {
            bps: f("bps")?,
            max_err: f("max_err")?,
            rms_err: f("rms_err")?,
            enc_msps: f("enc_msps")?,
            dec_msps: f("dec_msps")?,
            bound_ok: v.get("bound_ok")?.as_bool()?,
            note: s("note").unwrap_or_default(),
        }),
    };
    Some(PeerRow {
        codec: s("codec")?,
        dem: s("dem")?,
        eps: f("eps"),
        result,
    })
}

/// Measures the peers on `dems` at `eps`, or says why not (the `Err` is a message to print,
/// not a failure of the report).
pub fn measure(
    dems: &[(String, &Dem)],
    eps: &[f64],
    runs: usize,
    work: &Path,
    venv: Option<&Path>,
) -> Result<Peers, String> {
    let venv = venv
        .map(Path::to_path_buf)
        .or_else(default_venv)
        .ok_or("no venv directory: HOME is not set and --venv was not given")?;
    if Command::new("python3")
        .arg("--version")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_err()
    {
        return Err("python3 not found".into());
    }
    let python = prepare_venv(&venv).map_err(|e| format!("{e:#}"))?;
    run_harness(&python, dems, eps, runs, work).map_err(|e| format!("{e:#}"))
}

fn run_harness(
    python: &Path,
    dems: &[(String, &Dem)],
    eps: &[f64],
    runs: usize,
    work: &Path,
) -> Result<Peers> {
    std::fs::create_dir_all(work)?;
    // The harness gets exactly the values we verify against (f64, NaN at nodata), so both sides
    // measure error against the same numbers.
    let mut files = Vec::new();
    let mut manifest = Vec::new();
    for (name, dem) in dems {
        let path = work.join(format!("{name}.f64"));
        let mut w = std::io::BufWriter::new(std::fs::File::create(&path)?);
        for i in 0..dem.values.len() {
            let v = if dem.is_valid(i) {
                dem.values[i]
            } else {
                f64::NAN
            };
            w.write_all(&v.to_le_bytes())?;
        }
        w.flush()?;
        manifest.push(serde_json::json!({
            "name": name, "path": path, "width": dem.width, "height": dem.height,
            "quantum": detect_quantum(dem),
        }));
        files.push(path);
    }
    let mpath = work.join("manifest.json");
    std::fs::write(
        &mpath,
        serde_json::to_vec_pretty(
            &serde_json::json!({"eps": eps, "runs": runs, "dems": manifest}),
        )?,
    )?;
    eprintln!("peers: running bench/peers.py");
    let o = Command::new(python)
        .arg(harness_dir().join("peers.py"))
        .arg("--manifest")
        .arg(&mpath)
        .stdin(Stdio::null())
        .stderr(Stdio::inherit())
        .output()?;
    for f in files {
        // Up to a few hundred MB of raw samples: not worth keeping.
        let _ = std::fs::remove_file(f);
    }
    if !o.status.success() {
        bail!("bench/peers.py failed ({})", o.status);
    }
    let mut versions = String::new();
    let mut rows = Vec::new();
    for line in String::from_utf8_lossy(&o.stdout).lines() {
        let v: Value = serde_json::from_str(line)
            .with_context(|| format!("bench/peers.py printed {line:?}"))?;
        if let Some(m) = v.get("versions").and_then(Value::as_object) {
            versions = m
                .iter()
                .map(|(k, v)| format!("{k} {}", v.as_str().unwrap_or("?")))
                .collect::<Vec<_>>()
                .join(", ");
        } else {
            rows.push(parse_row(&v).with_context(|| format!("bad peer row {line}"))?);
        }
    }
    Ok(Peers { versions, rows })
}

#[cfg(test)]
mod tests {
    use super::parse_row;

    #[test]
    fn rows_and_skips() {
        let r = parse_row(&serde_json::json!({"codec": "SZ3", "dem": "a", "eps": 1.0,
            "bps": 2.5, "max_err": 0.99, "rms_err": 0.5, "enc_msps": 10.0, "dec_msps": 20.0,
            "bound_ok": true, "note": ""}))
        .unwrap();
        assert_eq!(r.eps, Some(1.0));
        assert_eq!(r.result.unwrap().bps, 2.5);
        let r = parse_row(
            &serde_json::json!({"codec": "zstd", "dem": "a", "eps": null,
            "bps": 8.0, "max_err": 0.0, "rms_err": 0.0, "enc_msps": 1.0, "dec_msps": 2.0,
            "bound_ok": true}),
        )
        .unwrap();
        assert_eq!(r.eps, None);
        let r = parse_row(
            &serde_json::json!({"codec": "JPEG-LS", "dem": "a", "eps": 0.05, "skipped": "16 bits"}),
        )
        .unwrap();
        assert_eq!(r.result.unwrap_err(), "16 bits");
        assert!(parse_row(&serde_json::json!({"codec": "x", "dem": "a", "eps": 1.0})).is_none());
    }
}
