//! `gazelight batch MANIFEST --slurm [--submit]`: a Slurm job-array script
//! whose task K runs `gazelight batch MANIFEST --out OUT --task K --tasks N`
//! (rows K, K + N, …). The script names this executable, the manifest and
//! the output folder by absolute path, so the cluster's nodes must see
//! them at the same paths (a shared file system). When the array has
//! ended, `gazelight batch MANIFEST --out OUT --collect` writes the summary.

use std::path::Path;

use anyhow::{Context, bail};

use super::BatchArgs;
use super::manifest::Row;
use super::state::State;

/// Slurm's default `MaxArraySize` is 1001 (indices 0–1000).
const MAX_ARRAY_TASKS: usize = 1000;

/// `s` quoted for a POSIX shell.
fn sh_quote(s: &str) -> String {
    format!("'{}'", s.replace('\'', "'\\''"))
}

/// The job-array script.
pub fn script(exe: &Path, manifest: &Path, out: &Path, tasks: usize, extra: &[String]) -> String {
    let mut s = String::from("#!/bin/bash\n");
    s.push_str("#SBATCH --job-name=gazelight-batch\n");
    s.push_str(&format!("#SBATCH --array=0-{}\n", tasks.saturating_sub(1)));
    s.push_str("#SBATCH --ntasks=1\n#SBATCH --cpus-per-task=1\n");
    s.push_str(&format!(
        "#SBATCH --output={}\n",
        out.join(super::state::STATE_DIR)
            .join("slurm-%A_%a.out")
            .display()
    ));
    for e in extra {
        s.push_str(&format!("#SBATCH {e}\n"));
    }
    s.push_str(&format!(
        "# Written by `gazelight batch --slurm`: task K replays rows K, K+{tasks}, … of the \
         manifest;\n# when the array has ended: {} batch {} --out {} --collect\n",
        sh_quote(&exe.display().to_string()),
        sh_quote(&manifest.display().to_string()),
        sh_quote(&out.display().to_string()),
    ));
    s.push_str("set -eu\n");
    s.push_str(&format!(
        "exec {} batch {} --out {} --task \"$SLURM_ARRAY_TASK_ID\" --tasks {tasks}\n",
        sh_quote(&exe.display().to_string()),
        sh_quote(&manifest.display().to_string()),
        sh_quote(&out.display().to_string()),
    ));
    s
}

/// Writes `OUT/_batch/batch.sbatch` and, with `--submit`, runs `sbatch`.
pub fn write_and_submit(
    args: &BatchArgs,
    rows: &[Row],
    out: &Path,
    state: &State,
) -> anyhow::Result<()> {
    let tasks = args.tasks.unwrap_or(rows.len().min(MAX_ARRAY_TASKS));
    if tasks == 0 || tasks > MAX_ARRAY_TASKS {
        bail!("--tasks {tasks}: expected 1 to {MAX_ARRAY_TASKS} array tasks");
    }
    let tasks = tasks.min(rows.len());
    for e in &args.sbatch {
        if !e.starts_with('-') || e.contains(['\n', '\r']) {
            bail!("--sbatch {e:?}: expected one sbatch option (e.g. --partition=short)");
        }
    }
    let exe = std::env::current_exe().context("cannot find gazelight's own executable")?;
    let abs = |p: &Path| {
        std::fs::canonicalize(p).with_context(|| format!("cannot resolve {}", p.display()))
    };
    let manifest = abs(&args.manifest)?;
    let out = abs(out)?;
    let path = state.dir().join("batch.sbatch");
    std::fs::write(&path, script(&exe, &manifest, &out, tasks, &args.sbatch))
        .with_context(|| format!("cannot write {}", path.display()))?;
    println!(
        "wrote {} ({} rows in {tasks} array tasks)",
        path.display(),
        rows.len()
    );
    let collect = format!(
        "{} batch {} --out {} --collect",
        sh_quote(&exe.display().to_string()),
        sh_quote(&manifest.display().to_string()),
        sh_quote(&out.display().to_string())
    );
    if !args.submit {
        println!(
            "submit it with: sbatch {}",
            sh_quote(&path.display().to_string())
        );
        println!("when the array has ended: {collect}");
        return Ok(());
    }
    let o = std::process::Command::new("sbatch")
        .arg("--parsable")
        .arg(&path)
        .output()
        .context("cannot run sbatch (is Slurm's client installed and on PATH?)")?;
    if !o.status.success() {
        bail!(
            "sbatch {}: {}",
            path.display(),
            String::from_utf8_lossy(&o.stderr).trim()
        );
    }
    let job = String::from_utf8_lossy(&o.stdout).trim().to_owned();
    println!("submitted job array {job} ({tasks} tasks)");
    println!("when it has ended: {collect}");
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_script_runs_one_slice_per_array_task() {
        let s = script(
            Path::new("/opt/g l/gazelight"),
            Path::new("/data/it's.csv"),
            Path::new("/scratch/out"),
            4,
            &["--partition=short".to_owned()],
        );
        assert!(s.starts_with("#!/bin/bash\n"), "{s}");
        assert!(s.contains("#SBATCH --array=0-3\n"), "{s}");
        assert!(s.contains("#SBATCH --partition=short\n"), "{s}");
        assert!(
            s.contains(
                "exec '/opt/g l/gazelight' batch '/data/it'\\''s.csv' --out '/scratch/out' \
                 --task \"$SLURM_ARRAY_TASK_ID\" --tasks 4\n"
            ),
            "{s}"
        );
        // bash reads it: `bash -n` checks the syntax.
        let dir = std::env::temp_dir().join(format!("gazelight-sbatch-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let p = dir.join("batch.sbatch");
        std::fs::write(&p, &s).unwrap();
        let ok = std::process::Command::new("bash")
            .arg("-n")
            .arg(&p)
            .status()
            .unwrap();
        assert!(ok.success());
        let _ = std::fs::remove_dir_all(&dir);
    }
}
