//! Embeds the git commit this `nudge` is built from as `NUDGE_GIT_SHA` (read by
//! `nudge::GIT_SHA`, recorded in every `provenance.json`): `$NUDGE_GIT_SHA` when set (a build
//! from a source archive can name its commit), else `git rev-parse HEAD` of the checkout, else
//! `"unknown"` (no git, or not a checkout). Rebuilt when HEAD or the branch it names moves.

use std::path::Path;
use std::process::Command;

/// `git <args>` in the crate's directory, its trimmed stdout when it succeeds.
fn git(args: &[&str]) -> Option<String> {
    let dir = std::env::var_os("CARGO_MANIFEST_DIR")?;
    let out = Command::new("git")
        .args(args)
        .current_dir(dir)
        .output()
        .ok()?;
    if !out.status.success() {
        return None;
    }
    let text = String::from_utf8(out.stdout).ok()?;
    let text = text.trim();
    (!text.is_empty()).then(|| text.to_string())
}

fn main() {
    println!("cargo:rerun-if-env-changed=NUDGE_GIT_SHA");
    let sha = match std::env::var("NUDGE_GIT_SHA") {
        Ok(s) if !s.trim().is_empty() => s.trim().to_string(),
        _ => {
            // Rebuild when the commit moves: HEAD itself, the branch it names, packed refs.
            for path in ["HEAD", "packed-refs"]
                .into_iter()
                .map(str::to_string)
                .chain(git(&["symbolic-ref", "-q", "HEAD"]))
            {
                if let Some(p) = git(&["rev-parse", "--git-path", &path])
                    && Path::new(&p).exists()
                {
                    let p = Path::new(&p);
                    let full = if p.is_absolute() {
                        p.to_path_buf()
                    } else {
                        Path::new(&std::env::var("CARGO_MANIFEST_DIR").unwrap_or_default()).join(p)
                    };
                    println!("cargo:rerun-if-changed={}", full.display());
                }
            }
            git(&["rev-parse", "HEAD"]).unwrap_or_else(|| "unknown".to_string())
        }
    };
    println!("cargo:rustc-env=NUDGE_GIT_SHA={sha}");
}
