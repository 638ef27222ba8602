//! `gazelight batch MANIFEST --slurm [--submit]`: a Slurm job-array script
//! whose task K runs `gazelight batch MANIFEST --out OUT --task K --tasks N`
//! (rows K, K + N, …). The script names this executable, the manifest and
//! the output folder by absolute path, so the cluster's nodes must see
//! them at the same paths (a shared file system). When the array has
//! ended, `gazelight batch MANIFEST --out OUT --collect` writes the summary.

use std::path::Path;

use crate::BatchOptions;
use crate::manifest::Row;
use crate::state::State;
use crate::{Context, Result};

/// Slurm's default `MaxArraySize` is 1001 (indices 0–1000).
const MAX_ARRAY_TASKS: usize = 1000;

/// `s` quoted for a POSIX shell: single quotes, inside which nothing
/// (`$`, backquotes, `\\`, `!`, `"`) is special; a `'` is written `'\\''`.
/// Only safe for text without control characters ([`script_text`] refuses
/// them): a newline inside quotes would still end a `#` comment line.
fn sh_quote(s: &str) -> String {
    format!("'{}'", s.replace('\'', "'\\''"))
}

/// `s` as one argument of an `#SBATCH` line. sbatch splits a directive at
/// white space and takes `'`, `"` and `\\` as quotes and escapes (as a
/// shell would, without expansions); in the `--output` file name `%` starts
/// a replacement (`%A`, `%a`). Every character but `[A-Za-z0-9/._+,:@=-]`
/// is escaped with a backslash and `%` is written `%%` (a literal `%`).
fn sbatch_arg(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '%' => out.push_str("%%"),
            c if c.is_ascii_alphanumeric() || "/._+,:@=-".contains(c) => out.push(c),
            c => {
                out.push('\\');
                out.push(c);
            }
        }
    }
    out
}

/// A path the script names, as UTF-8 text without control characters: a
/// newline (or CR, or any other control character) in a path written into
/// the script would end an `#SBATCH` or comment line and start a shell
/// line of its own, and a path that is not UTF-8 would be written as
/// another path. Both are refused, naming the path.
fn script_text<'a>(what: &str, p: &'a Path) -> Result<&'a str> {
    let Some(s) = p.to_str() else {
        bail!(
            "{what} {}: the path is not UTF-8; a Slurm script cannot name it (rename it)",
            p.display()
        );
    };
    if let Some(c) = s.chars().find(|c| c.is_control()) {
        bail!(
            "{what} {s:?}: the path holds the control character {c:?}; a Slurm script \
             cannot name it safely (rename it)"
        );
    }
    Ok(s)
}

/// The job-array script. Every path is checked by [`script_text`] and
/// written quoted (single quotes on shell lines, backslash escapes on
/// `#SBATCH` lines); `extra` options are checked by the caller.
pub fn script(
    exe: &Path,
    manifest: &Path,
    out: &Path,
    tasks: usize,
    extra: &[String],
) -> Result<String> {
    let exe = script_text("gazelight's executable", exe)?;
    let manifest = script_text("the manifest", manifest)?;
    let out = script_text("--out", out)?;
    let mut s = String::from("#!/bin/bash\n");
    s.push_str("#SBATCH --job-name=gazelight-batch\n");
    s.push_str(&format!("#SBATCH --array=0-{}\n", tasks.saturating_sub(1)));
    s.push_str("#SBATCH --ntasks=1\n#SBATCH --cpus-per-task=1\n");
    s.push_str(&format!(
        "#SBATCH --output={}/{}/slurm-%A_%a.out\n",
        sbatch_arg(out.trim_end_matches('/')),
        crate::state::STATE_DIR,
    ));
    for e in extra {
        s.push_str(&format!("#SBATCH {e}\n"));
    }
    s.push_str(&format!(
        "# Written by `gazelight batch --slurm`: task K replays rows K, K+{tasks}, … of the \
         manifest;\n# when the array has ended: {} batch {} --out {} --collect\n",
        sh_quote(exe),
        sh_quote(manifest),
        sh_quote(out),
    ));
    s.push_str("set -eu\n");
    s.push_str(&format!(
        "exec {} batch {} --out {} --task \"$SLURM_ARRAY_TASK_ID\" --tasks {tasks}\n",
        sh_quote(exe),
        sh_quote(manifest),
        sh_quote(out),
    ));
    Ok(s)
}

/// Refuses, before anything is created, a manifest, `--out` or executable
/// path that a script cannot name ([`script_text`]).
pub fn check_paths(manifest: &Path, out: &Path) -> Result<()> {
    let exe = std::env::current_exe().context("cannot find gazelight's own executable")?;
    script_text("gazelight's executable", &exe)?;
    script_text("the manifest", manifest)?;
    script_text("--out", out)?;
    Ok(())
}

/// Writes `OUT/_batch/batch.sbatch` and, with `--submit`, runs `sbatch`.
pub fn write_and_submit(
    args: &BatchOptions,
    rows: &[Row],
    out: &Path,
    state: &State,
) -> Result<()> {
    let tasks = args.tasks.unwrap_or(rows.len().min(MAX_ARRAY_TASKS));
    if tasks == 0 || tasks > MAX_ARRAY_TASKS {
        bail!("--tasks {tasks}: expected 1 to {MAX_ARRAY_TASKS} array tasks");
    }
    let tasks = tasks.min(rows.len());
    for e in &args.sbatch {
        if !e.starts_with('-') || e.chars().any(char::is_control) {
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
    let text = script(&exe, &manifest, &out, tasks, &args.sbatch)?;
    std::fs::write(&path, text).with_context(|| format!("cannot write {}", path.display()))?;
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
        )
        .unwrap();
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

    /// sbatch's own reading of one `#SBATCH` argument (slurm's
    /// `src/sbatch/opt.c`, `_get_argument`): up to unquoted white space,
    /// `\` escapes the next character, `'` and `"` quote.
    fn sbatch_unquote(line: &str) -> String {
        let mut out = String::new();
        let (mut quote, mut escape) = (None, false);
        for c in line.chars() {
            if escape {
                escape = false;
            } else if c == '\\' {
                escape = true;
                continue;
            } else if let Some(q) = quote {
                if c == q {
                    quote = None;
                    continue;
                }
            } else if c == '\'' || c == '"' {
                quote = Some(c);
                continue;
            } else if c.is_whitespace() {
                break;
            }
            out.push(c);
        }
        out
    }

    #[test]
    fn hostile_paths_reach_the_command_as_they_are_and_run_nothing() {
        let dir = std::env::temp_dir().join(format!("gazelight-sbatch-x-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        // Spaces, both quotes, a command substitution, a backquote, `;`,
        // `#`, `%` and `\\`: each would run or split something if a shell
        // or sbatch read it unquoted.
        let evil = dir.join("a b'c\"d $(touch PWNED1) `touch PWNED2`; #x %A \\n");
        std::fs::create_dir_all(&evil).unwrap();
        // The "executable": a script that writes the arguments it got.
        let exe = evil.join("fake gazelight");
        std::fs::write(
            &exe,
            format!(
                "#!/bin/sh\nprintf '%s\\n' \"$@\" > '{}'\n",
                dir.join("args.txt").display()
            ),
        )
        .unwrap();
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(&exe, std::fs::Permissions::from_mode(0o755)).unwrap();
        let manifest = evil.join("rows $(id).csv");
        let out = evil.join("out");
        let s = script(&exe, &manifest, &out, 3, &[]).unwrap();
        let p = dir.join("batch.sbatch");
        std::fs::write(&p, &s).unwrap();
        let status = std::process::Command::new("bash")
            .arg(&p)
            .current_dir(&dir)
            .env("SLURM_ARRAY_TASK_ID", "2")
            .status()
            .unwrap();
        assert!(status.success(), "{s}");
        let args = std::fs::read_to_string(dir.join("args.txt")).unwrap();
        let want = [
            "batch",
            manifest.to_str().unwrap(),
            "--out",
            out.to_str().unwrap(),
            "--task",
            "2",
            "--tasks",
            "3",
        ]
        .map(|a| format!("{a}\n"))
        .concat();
        assert_eq!(args, want, "{s}");
        for pwned in ["PWNED1", "PWNED2"] {
            assert!(!dir.join(pwned).exists(), "{pwned} ran:\n{s}");
        }
        // sbatch reads the log's folder back as the path it is, `%A`
        // written `%%A` (a literal %) and its own `%A_%a` kept.
        let output = s
            .lines()
            .find_map(|l| l.strip_prefix("#SBATCH --output="))
            .unwrap();
        let want = format!("{}/_batch/slurm-%A_%a.out", out.display()).replace("%A ", "%%A ");
        assert_eq!(sbatch_unquote(output), want, "{s}");
        let _ = std::fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_path_with_a_newline_or_other_control_character_is_refused() {
        for bad in [
            "/data/x\nsrun rm -rf ~\n.csv",
            "/data/x\r.csv",
            "/data/\u{1b}[2J.csv",
        ] {
            let e = script(
                Path::new("/opt/gazelight"),
                Path::new(bad),
                Path::new("/scratch/out"),
                2,
                &[],
            )
            .unwrap_err()
            .to_string();
            assert!(
                e.contains("the manifest") && e.contains("control character"),
                "{e}"
            );
        }
        let e = script(
            Path::new("/opt/gazelight"),
            Path::new("/data/m.csv"),
            Path::new("/scratch/o\nut"),
            2,
            &[],
        )
        .unwrap_err()
        .to_string();
        assert!(e.starts_with("--out"), "{e}");
    }
}
