//! `cbdam web-export DIR`: the browser viewer as static files, for any static host with Range
//! support (the page reads a `.cbdam` file with Range requests, like PMTiles).
//!
//! The viewer's files are the bundle `scripts/web-build.sh` writes (target/web-bundle); they are
//! not built into the `cbdam` binary, which would make every native build compile the wasm
//! module too. The bundle is found at `--bundle DIR`, `$CBDAM_WEB_BUNDLE`, `target/web-bundle`
//! under the working directory, or `web-bundle` beside or above the binary (target/debug/cbdam
//! finds target/web-bundle).
//!
//! With `--repo FILE` the repository is copied into DIR and the page opens it when no
//! `?repo=` is given; with `--repo URL` the page opens that URL (its server must allow the
//! page's origin and honour Range requests). `--colour FILE_OR_URL` does the same for a colour
//! repository the page drapes over it without `?colour=` (two files are checked to pair first).

use std::path::{Path, PathBuf};

use anyhow::{Context, Result, bail};
use cbdam_codec::repository::Repository;
use clap::Args;

/// Write the browser viewer as static files into DIR, for any static server that honours
/// Range requests: open DIR/index.html?repo=URL of a `.cbdam` file (or, with --repo, just
/// index.html; --colour adds a colour repository draped over it, as `?colour=URL` does).
///
/// The viewer's files come from the bundle scripts/web-build.sh writes (target/web-bundle):
/// --bundle DIR, else $CBDAM_WEB_BUNDLE, else target/web-bundle in the working directory,
/// else web-bundle beside or above the cbdam binary.
#[derive(Args, Debug)]
pub struct WebExportArgs {
    /// Folder to write (created if needed; files of the same names are replaced).
    #[arg(value_name = "DIR")]
    dir: PathBuf,
    /// The repository the page opens without `?repo=`: a .cbdam file (copied into DIR) or an
    /// http(s) URL of one (its server must honour Range requests and allow the page's origin).
    #[arg(long, value_name = "FILE_OR_URL")]
    repo: Option<String>,
    /// A colour repository the page drapes over --repo without `?colour=` (built by `cbdam
    /// build IMAGE --colour --like REPO`): a .cbdam file (copied into DIR; checked to pair with
    /// --repo) or an http(s) URL.
    #[arg(long, value_name = "FILE_OR_URL", requires = "repo")]
    colour: Option<String>,
    /// The viewer's bundle (default: found as the command's help says).
    #[arg(long, value_name = "DIR")]
    bundle: Option<PathBuf>,
}

/// The slots in the bundle's index.html (client/web/www/index.html) that name the repository
/// opened without `?repo=` and the colour repository draped without `?colour=`.
const REPO_SLOT: &str = "cbdam-repo";
const COLOUR_SLOT: &str = "cbdam-colour";

/// Where the bundle is looked for when `--bundle` is not given, in order.
fn bundle_candidates() -> Vec<PathBuf> {
    let mut dirs = Vec::new();
    if let Some(dir) = std::env::var_os("CBDAM_WEB_BUNDLE") {
        dirs.push(PathBuf::from(dir));
    }
    dirs.push(PathBuf::from("target/web-bundle"));
    if let Ok(exe) = std::env::current_exe()
        && let Some(bin_dir) = exe.parent()
    {
        dirs.push(bin_dir.join("web-bundle"));
        if let Some(up) = bin_dir.parent() {
            dirs.push(up.join("web-bundle"));
        }
    }
    dirs
}

fn is_bundle(dir: &Path) -> bool {
    cbdam_server::web::REQUIRED
        .iter()
        .all(|f| dir.join(f).is_file())
}

/// The bundle to export: `--bundle` (which must be one), else the first candidate that is one.
fn find_bundle(given: Option<&Path>) -> Result<PathBuf> {
    if let Some(dir) = given {
        if let Some(missing) = cbdam_server::web::REQUIRED
            .iter()
            .find(|f| !dir.join(f).is_file())
        {
            bail!(
                "{} is not the viewer's bundle: {missing} is missing (build it with \
                 scripts/web-build.sh, which writes target/web-bundle)",
                dir.display()
            );
        }
        return Ok(dir.to_path_buf());
    }
    let candidates = bundle_candidates();
    candidates
        .iter()
        .find(|d| is_bundle(d))
        .cloned()
        .ok_or_else(|| {
            let looked: Vec<String> = candidates.iter().map(|d| d.display().to_string()).collect();
            anyhow::anyhow!(
                "no viewer bundle found (looked in {}): build it with scripts/web-build.sh in the \
             source tree (it writes target/web-bundle), or pass --bundle DIR",
                looked.join(", ")
            )
        })
}

/// What the page opens by default.
enum DefaultRepo {
    /// A local repository, copied into the export under this file name.
    File(PathBuf, String),
    /// A URL, left as it is.
    Url(String),
}

impl DefaultRepo {
    /// What the page's slot says: the copy's file name, or the URL.
    fn location(&self) -> &str {
        match self {
            DefaultRepo::File(_, name) => name,
            DefaultRepo::Url(url) => url,
        }
    }
}

/// The repository given to `flag` (`--repo`, `--colour`).
fn default_repo(flag: &str, repo: &str) -> Result<DefaultRepo> {
    if repo.starts_with("http://") || repo.starts_with("https://") {
        return Ok(DefaultRepo::Url(repo.to_string()));
    }
    let path = PathBuf::from(repo);
    if !path.is_file() {
        bail!("{flag} {repo}: no such file (give a .cbdam file or an http(s):// URL)");
    }
    // Checked now, not when someone opens the page.
    Repository::open(&path).with_context(|| format!("{flag} {repo}: not a readable repository"))?;
    let name = path
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .with_context(|| format!("{flag} {repo}: no file name"))?;
    Ok(DefaultRepo::File(path, name))
}

/// A colour repository for the terrain `repo`: two files are checked to pair as `cbdam render
/// --colour` pairs them (a URL is the page's to check), and must not share a file name.
fn default_colour(repo: &DefaultRepo, colour: &str) -> Result<DefaultRepo> {
    let c = default_repo("--colour", colour)?;
    if let (DefaultRepo::File(rp, rn), DefaultRepo::File(cp, cn)) = (repo, &c) {
        if rn == cn {
            bail!("--colour {colour}: the same file name as --repo's ({rn}): rename one");
        }
        // Paired as `cbdam render --colour` pairs them.
        crate::session::terrain_source(&rp.to_string_lossy(), Some(&cp.to_string_lossy()))
            .with_context(|| format!("--colour {colour}"))?;
    }
    Ok(c)
}

/// `page` with the slot `<meta name="NAME" content="">` filled with `value`; an error if the
/// bundle's page has no such slot.
fn fill_slot(page: &str, name: &str, value: &str, bundle: &Path) -> Result<String> {
    let slot = format!(r#"<meta name="{name}" content="">"#);
    if !page.contains(&slot) {
        bail!(
            "{}/index.html has no {name} slot (an older bundle?): rebuild it with \
             scripts/web-build.sh",
            bundle.display()
        );
    }
    let filled = format!(
        r#"<meta name="{name}" content="{}">"#,
        escape_attribute(value)
    );
    Ok(page.replacen(&slot, &filled, 1))
}

/// Escapes text for an HTML attribute.
fn escape_attribute(s: &str) -> String {
    s.replace('&', "&amp;")
        .replace('"', "&quot;")
        .replace('<', "&lt;")
        .replace('>', "&gt;")
}

pub fn run(args: &WebExportArgs) -> Result<()> {
    let bundle = find_bundle(args.bundle.as_deref())?;
    let repo = args
        .repo
        .as_deref()
        .map(|r| default_repo("--repo", r))
        .transpose()?;
    let colour = match (&repo, args.colour.as_deref()) {
        (Some(r), Some(c)) => Some(default_colour(r, c)?),
        _ => None,
    };
    let out = &args.dir;
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    // Copying the bundle onto itself would truncate its files, and filling in its page would
    // remove the slot later exports fill.
    if std::fs::canonicalize(out).ok() == std::fs::canonicalize(&bundle).ok() {
        bail!(
            "{} is the viewer's bundle itself: export into another folder",
            out.display()
        );
    }

    let mut files = 0;
    let mut entries: Vec<_> = std::fs::read_dir(&bundle)
        .with_context(|| format!("reading {}", bundle.display()))?
        .collect::<Result<_, _>>()
        .with_context(|| format!("reading {}", bundle.display()))?;
    entries.sort_by_key(|e| e.file_name());
    for e in entries {
        let name = e.file_name();
        if !e.path().is_file() || name.to_string_lossy().starts_with('.') {
            continue;
        }
        let to = out.join(&name);
        if name == "index.html" {
            let page = std::fs::read_to_string(e.path())
                .with_context(|| format!("reading {}", e.path().display()))?;
            let mut page = page;
            if let Some(r) = &repo {
                page = fill_slot(&page, REPO_SLOT, r.location(), &bundle)?;
            }
            if let Some(c) = &colour {
                page = fill_slot(&page, COLOUR_SLOT, c.location(), &bundle)?;
            }
            std::fs::write(&to, page).with_context(|| format!("writing {}", to.display()))?;
        } else {
            std::fs::copy(e.path(), &to)
                .with_context(|| format!("copying {} to {}", e.path().display(), to.display()))?;
        }
        files += 1;
    }
    for r in repo.iter().chain(&colour) {
        if let DefaultRepo::File(path, name) = r {
            let to = out.join(name);
            std::fs::copy(path, &to)
                .with_context(|| format!("copying {} to {}", path.display(), to.display()))?;
        }
    }
    let opens = match (&repo, &colour) {
        (Some(r), None) => format!("index.html (opens {})", r.location()),
        (Some(r), Some(c)) => format!(
            "index.html (opens {} with {} draped)",
            r.location(),
            c.location()
        ),
        (None, _) => "index.html?repo=URL".to_string(),
    };
    println!(
        "web-export: the viewer ({files} files from {}) is in {}; serve that folder from any \
         static server with Range support and open {opens}",
        bundle.display(),
        out.display()
    );
    Ok(())
}
