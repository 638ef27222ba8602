//! Every shell command and configuration example in README.md and
//! docs/*.md runs here, against the built binary, so none can go stale.
//!
//! Blocks run: ```` ```sh ```` and ```` ```console ```` (commands; in a
//! console block only the `$ ` lines are commands, the rest is output) and
//! ```` ```toml ```` (configuration files; with `config batch`, a batch
//! manifest) and ```` ```csv ```` (batch manifests, checked by `gazelight
//! batch` parse-only). Other fences (`text`, `rust`, …) are prose and not
//! run.
//!
//! Commands understood: `gazelight ARGS` and `cargo run -p gazelight -- ARGS`
//! (both: the built binary with ARGS), with leading `VAR=value` assignments
//! as its environment; `bash .ci/test` is checked to be the workspace test
//! entry, not run (it runs this test). Anything else fails the test: write
//! it as prose or in a `text` block. Trailing `# comments` and `\`
//! continuations are understood.
//!
//! Hidden directives shorten or qualify a block: HTML comments, one per line,
//! in the lines right before its fence (nothing else in between):
//!
//! | directive | effect |
//! | --- | --- |
//! | `<!-- doc-test: parse-only -->` | each command runs with `GAZELIGHT_PARSE_ONLY=1`: the binary's real argument parser and configuration loader check it, nothing is opened (for commands that need a live tracker, a headset or hardware) |
//! | `<!-- doc-test: set FLAG VALUE -->` | every gazelight command of the block gets `FLAG VALUE` (replacing its own value of FLAG, or appended), e.g. `set --frames 2` |
//! | `<!-- doc-test: append ARGS… -->` | ARGS appended to every gazelight command of the block |
//! | `<!-- doc-test: data NAME=REL -->` | before the block, `NAME` in the working directory links to `REL` under the shared test data; without the data the block is skipped (SKIP) outside CI and fails in CI |
//! | `<!-- doc-test: config run\|render\|batch\|layer -->` | a toml block is loaded by that command's loader (`--config`, parse-only; `batch`: as its manifest; `layer`: as the OpenXR layer's `layer.toml`, by `gazelight layer status` with `GAZELIGHT_LAYER_CONFIG`, parse-only); default `run` |
//! | `<!-- doc-test: save NAME -->` | a toml or csv block is also saved as `NAME` in the working directory, for later blocks of the same page |
//! | `<!-- doc-test: input -->` | a csv block is an input file for later blocks (with `save NAME`), not a batch manifest: saved, not run |
//!
//! Each page runs in its own temporary working directory, its blocks in
//! page order (`GAZELIGHT_DOC_PAGE=NAME`: only the pages whose path holds
//! NAME). `a_broken_page_fails` shows that a misspelt flag, a bad TOML
//! key, an unknown command and a missing directive target each fail.

#![allow(clippy::unwrap_used, clippy::expect_used)] // test code may panic on a failed setup

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

/// Longest a documented command may run.
const COMMAND_LIMIT: Duration = Duration::from_secs(300);

#[derive(Clone, Copy, Debug, PartialEq)]
enum Lang {
    Shell,
    Console,
    Toml,
    /// A batch manifest (CSV).
    Csv,
}

/// One fenced block to run.
#[derive(Debug)]
struct Block {
    /// 1-based line of the opening fence.
    line: usize,
    lang: Lang,
    /// The `doc-test:` directives before it.
    directives: Vec<Vec<String>>,
    body: String,
}

/// The runnable blocks of a markdown page, with their directives.
fn extract(markdown: &str) -> Vec<Block> {
    let mut blocks = Vec::new();
    let mut pending: Vec<Vec<String>> = Vec::new();
    let mut lines = markdown.lines().enumerate();
    while let Some((i, line)) = lines.next() {
        let trimmed = line.trim();
        if let Some(d) = trimmed
            .strip_prefix("<!-- doc-test:")
            .and_then(|d| d.strip_suffix("-->"))
        {
            pending.push(d.split_whitespace().map(str::to_owned).collect());
            continue;
        }
        let Some(info) = trimmed.strip_prefix("```") else {
            if !trimmed.is_empty() {
                pending.clear();
            }
            continue;
        };
        let lang = match info.split_whitespace().next().unwrap_or("") {
            "sh" | "bash" | "shell" => Some(Lang::Shell),
            "console" => Some(Lang::Console),
            "toml" => Some(Lang::Toml),
            "csv" => Some(Lang::Csv),
            _ => None,
        };
        let mut body = String::new();
        for (_, l) in lines.by_ref() {
            if l.trim_start().starts_with("```") {
                break;
            }
            body.push_str(l);
            body.push('\n');
        }
        if let Some(lang) = lang {
            blocks.push(Block {
                line: i + 1,
                lang,
                directives: std::mem::take(&mut pending),
                body,
            });
        }
        pending.clear();
    }
    blocks
}

/// The commands of a shell or console block: continuations joined,
/// comments dropped.
fn commands(block: &Block) -> Vec<String> {
    let mut out = Vec::new();
    let mut current = String::new();
    let mut in_command = false;
    for raw in block.body.lines() {
        let line = if in_command {
            raw.trim()
        } else {
            let t = raw.trim();
            match block.lang {
                Lang::Console => match t.strip_prefix("$ ") {
                    Some(c) => c.trim(),
                    None => continue,
                },
                _ => {
                    if t.is_empty() || t.starts_with('#') {
                        continue;
                    }
                    t
                }
            }
        };
        match line.strip_suffix('\\') {
            Some(head) => {
                current.push_str(head);
                current.push(' ');
                in_command = true;
            }
            None => {
                current.push_str(line);
                out.push(strip_comment(&current).trim().to_owned());
                current.clear();
                in_command = false;
            }
        }
    }
    if !current.trim().is_empty() {
        out.push(strip_comment(&current).trim().to_owned());
    }
    out
}

/// `cmd args  # comment` → `cmd args` (a `#` inside quotes stays).
fn strip_comment(line: &str) -> &str {
    let (mut single, mut double) = (false, false);
    let mut prev = ' ';
    for (i, c) in line.char_indices() {
        match c {
            '\'' if !double => single = !single,
            '"' if !single => double = !double,
            '#' if !single && !double && prev.is_whitespace() => return &line[..i],
            _ => {}
        }
        prev = c;
    }
    line
}

/// Shell-like words: whitespace-separated, single and double quotes group.
fn words(line: &str) -> Result<Vec<String>, String> {
    let mut out = Vec::new();
    let mut word = String::new();
    let mut started = false;
    let mut chars = line.chars();
    while let Some(c) = chars.next() {
        match c {
            '\'' => {
                started = true;
                loop {
                    match chars.next() {
                        Some('\'') => break,
                        Some(c) => word.push(c),
                        None => return Err(format!("unclosed ' in `{line}`")),
                    }
                }
            }
            '"' => {
                started = true;
                loop {
                    match chars.next() {
                        Some('"') => break,
                        Some('\\') => word.extend(chars.next()),
                        Some(c) => word.push(c),
                        None => return Err(format!("unclosed \" in `{line}`")),
                    }
                }
            }
            c if c.is_whitespace() => {
                if started {
                    out.push(std::mem::take(&mut word));
                    started = false;
                }
            }
            c => {
                started = true;
                word.push(c);
            }
        }
    }
    if started {
        out.push(word);
    }
    Ok(out)
}

/// What a page needs from the world: where the shared data is, the binary,
/// the repository root.
struct Env {
    binary: PathBuf,
    repo: PathBuf,
    data: PathBuf,
}

impl Env {
    fn new() -> Self {
        Self {
            binary: PathBuf::from(env!("CARGO_BIN_EXE_gazelight")),
            repo: Path::new(env!("CARGO_MANIFEST_DIR")).join("../.."),
            data: common::shared(""),
        }
    }
}

/// Outcome of checking one page.
#[derive(Default)]
struct Report {
    ran: usize,
    skipped: Vec<String>,
    failures: Vec<String>,
}

/// Runs every block of `markdown` in the fresh directory `work`.
fn check_page(env: &Env, name: &str, markdown: &str, work: &Path) -> Report {
    let mut report = Report::default();
    let _ = std::fs::remove_dir_all(work);
    std::fs::create_dir_all(work).expect("work dir");
    for block in extract(markdown) {
        let at = format!("{name}:{}", block.line);
        match run_block(env, &block, work, &mut report) {
            Ok(()) => {}
            Err(e) => report.failures.push(format!("{at}: {e}")),
        }
    }
    report
}

fn directive<'a>(block: &'a Block, name: &str) -> impl Iterator<Item = &'a [String]> {
    block
        .directives
        .iter()
        .filter(move |d| d.first().is_some_and(|n| n == name))
        .map(|d| &d[1..])
}

fn run_block(env: &Env, block: &Block, work: &Path, report: &mut Report) -> Result<(), String> {
    const KNOWN: [&str; 7] = [
        "parse-only",
        "set",
        "append",
        "data",
        "config",
        "save",
        "input",
    ];
    for d in &block.directives {
        let name = d.first().map(String::as_str).unwrap_or("");
        if !KNOWN.contains(&name) {
            return Err(format!("unknown doc-test directive `{}`", d.join(" ")));
        }
    }
    for args in directive(block, "data") {
        let [spec] = args else {
            return Err(format!("`data` takes NAME=REL, got {args:?}"));
        };
        let (link, rel) = spec
            .split_once('=')
            .ok_or_else(|| format!("`data {spec}`: expected NAME=REL"))?;
        let target = env.data.join(rel);
        if !target.exists() {
            assert!(
                std::env::var_os("CI").is_none(),
                "CI must have the shared test data: {} missing",
                target.display()
            );
            report
                .skipped
                .push(format!("line {}: {} missing", block.line, target.display()));
            eprintln!("SKIP: {} missing", target.display());
            return Ok(());
        }
        let link = work.join(link);
        let _ = std::fs::remove_file(&link);
        std::os::unix::fs::symlink(&target, &link).map_err(|e| format!("link {spec}: {e}"))?;
    }
    match block.lang {
        Lang::Toml => run_toml(env, block, work, report),
        Lang::Csv => run_manifest(env, block, work, report, "csv"),
        Lang::Shell | Lang::Console => {
            let commands = commands(block);
            if commands.is_empty() {
                return Err("a command block without a command".into());
            }
            for command in commands {
                run_command(env, block, &command, work)?;
                report.ran += 1;
            }
            Ok(())
        }
    }
}

fn run_toml(env: &Env, block: &Block, work: &Path, report: &mut Report) -> Result<(), String> {
    let command = match directive(block, "config").next() {
        None => "run",
        Some([c]) if c == "batch" => return run_manifest(env, block, work, report, "toml"),
        Some([c]) if c == "run" || c == "render" || c == "layer" => c.as_str(),
        Some(other) => {
            return Err(format!(
                "`config` takes run, render, batch or layer, got {other:?}"
            ));
        }
    };
    let file = format!("block-{}.toml", block.line);
    std::fs::write(work.join(&file), &block.body).map_err(|e| e.to_string())?;
    for args in directive(block, "save") {
        let [name] = args else {
            return Err(format!("`save` takes one NAME, got {args:?}"));
        };
        std::fs::write(work.join(name), &block.body).map_err(|e| e.to_string())?;
    }
    if command == "layer" {
        // The layer reads its file from the environment, not a flag.
        let path = work.join(&file).to_string_lossy().into_owned();
        let argv = ["layer".to_owned(), "status".to_owned()];
        invoke(
            env,
            &argv,
            &[("GAZELIGHT_LAYER_CONFIG", path.as_str())],
            true,
            work,
        )
        .map_err(|e| format!("[layer config] {e}"))?;
        report.ran += 1;
        return Ok(());
    }
    let argv = vec![command.to_owned(), "--config".to_owned(), file];
    invoke(env, &argv, &[], true, work).map_err(|e| format!("[{command} config] {e}"))?;
    report.ran += 1;
    Ok(())
}

/// A batch manifest block (`ext`: csv or toml): saved, then checked by
/// `gazelight batch FILE` parse-only.
fn run_manifest(
    env: &Env,
    block: &Block,
    work: &Path,
    report: &mut Report,
    ext: &str,
) -> Result<(), String> {
    let file = format!("block-{}.{ext}", block.line);
    std::fs::write(work.join(&file), &block.body).map_err(|e| e.to_string())?;
    for args in directive(block, "save") {
        let [name] = args else {
            return Err(format!("`save` takes one NAME, got {args:?}"));
        };
        std::fs::write(work.join(name), &block.body).map_err(|e| e.to_string())?;
    }
    if directive(block, "input").next().is_some() {
        // An input file of later blocks (e.g. `replay --display-light`).
        return Ok(());
    }
    let argv = vec!["batch".to_owned(), file];
    invoke(env, &argv, &[], true, work).map_err(|e| format!("[batch manifest] {e}"))?;
    report.ran += 1;
    Ok(())
}

/// A documented gazelight command: its environment and arguments.
struct Invocation {
    vars: Vec<(String, String)>,
    args: Vec<String>,
}

/// The gazelight invocation of a documented command, `None` for the test
/// command, or why it cannot run.
fn gazelight_argv(words: &[String]) -> Result<Option<Invocation>, String> {
    let mut vars = Vec::new();
    let mut rest = words;
    while let Some((first, tail)) = rest.split_first() {
        let assignment = first.split_once('=').filter(|(k, _)| {
            !k.is_empty()
                && k.chars()
                    .all(|c| c.is_ascii_uppercase() || c.is_ascii_digit() || c == '_')
        });
        match assignment {
            Some((k, v)) => {
                vars.push((k.to_owned(), v.to_owned()));
                rest = tail;
            }
            None => break,
        }
    }
    let rest: Vec<&str> = rest.iter().map(String::as_str).collect();
    let owned = |args: &[&str]| args.iter().map(|s| (*s).to_owned()).collect();
    match rest.as_slice() {
        ["gazelight", args @ ..] | ["cargo", "run", "-p", "gazelight", "--", args @ ..] => {
            Ok(Some(Invocation {
                vars,
                args: owned(args),
            }))
        }
        ["bash", ".ci/test", ..] => Ok(None),
        _ => Err(format!(
            "not a command this test can run: `{}` (write it as prose or in a text block)",
            rest.join(" ")
        )),
    }
}

fn run_command(env: &Env, block: &Block, command: &str, work: &Path) -> Result<(), String> {
    let words = words(command)?;
    let Some(Invocation {
        vars,
        args: mut argv,
    }) = gazelight_argv(&words)?
    else {
        // `bash .ci/test`: the README's test command must stay the
        // workspace's test entry.
        let script = std::fs::read_to_string(env.repo.join(".ci/test"))
            .map_err(|e| format!("`{command}`: .ci/test: {e}"))?;
        if !script.contains("cargo test --workspace --all-targets") {
            return Err(format!(
                "`{command}`: .ci/test no longer runs the workspace tests"
            ));
        }
        return Ok(());
    };
    for args in directive(block, "set") {
        let [flag, value] = args else {
            return Err(format!("`set` takes FLAG VALUE, got {args:?}"));
        };
        match argv.iter().position(|a| a == flag) {
            Some(i) if i + 1 < argv.len() => argv[i + 1] = value.clone(),
            _ => argv.extend([flag.clone(), value.clone()]),
        }
    }
    for args in directive(block, "append") {
        argv.extend(args.iter().cloned());
    }
    let parse_only = directive(block, "parse-only").next().is_some();
    let vars: Vec<(&str, &str)> = vars.iter().map(|(k, v)| (k.as_str(), v.as_str())).collect();
    invoke(env, &argv, &vars, parse_only, work).map_err(|e| format!("`{command}`: {e}"))
}

/// Runs the binary in `work`; Ok when it exits 0 within [`COMMAND_LIMIT`].
fn invoke(
    env: &Env,
    argv: &[String],
    vars: &[(&str, &str)],
    parse_only: bool,
    work: &Path,
) -> Result<(), String> {
    let stderr_path = work.join(".doc-test-stderr");
    let stderr = std::fs::File::create(&stderr_path).map_err(|e| format!("stderr file: {e}"))?;
    let mut cmd = Command::new(&env.binary);
    cmd.args(argv)
        .current_dir(work)
        .env("RUST_LOG", "warn")
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(stderr);
    for (k, v) in vars {
        cmd.env(k, v);
    }
    if parse_only {
        cmd.env("GAZELIGHT_PARSE_ONLY", "1");
    }
    let mut child = cmd.spawn().map_err(|e| format!("spawn: {e}"))?;
    let started = Instant::now();
    let status = loop {
        match child.try_wait().map_err(|e| format!("wait: {e}"))? {
            Some(status) => break status,
            None if started.elapsed() > COMMAND_LIMIT => {
                let _ = child.kill();
                let _ = child.wait();
                return Err(format!("still running after {COMMAND_LIMIT:?}"));
            }
            None => std::thread::sleep(Duration::from_millis(20)),
        }
    };
    if status.success() {
        Ok(())
    } else {
        let stderr = std::fs::read_to_string(&stderr_path).unwrap_or_default();
        let tail: Vec<&str> = stderr.lines().rev().take(6).collect();
        Err(format!(
            "{}exit {:?}: {}",
            if parse_only { "parse-only " } else { "" },
            status.code(),
            tail.into_iter().rev().collect::<Vec<_>>().join(" | ")
        ))
    }
}

/// README.md and every page under docs/.
fn pages(repo: &Path) -> Vec<PathBuf> {
    let mut pages = vec![repo.join("README.md")];
    let mut docs: Vec<PathBuf> = std::fs::read_dir(repo.join("docs"))
        .expect("docs/")
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "md"))
        .collect();
    docs.sort();
    pages.extend(docs);
    // `GAZELIGHT_DOC_PAGE=NAME`: only the pages whose path holds NAME
    // (checking one page while writing it).
    if let Ok(only) = std::env::var("GAZELIGHT_DOC_PAGE") {
        pages.retain(|p| p.to_string_lossy().contains(only.as_str()));
    }
    pages
}

#[test]
fn every_documented_command_and_config_runs() {
    let env = Env::new();
    let mut failures = Vec::new();
    let mut ran = 0;
    for page in pages(&env.repo) {
        let name = page
            .strip_prefix(&env.repo)
            .unwrap_or(&page)
            .display()
            .to_string();
        let text = std::fs::read_to_string(&page).expect("page");
        let work = common::tmp_path(&name.replace(['/', '.'], "_"));
        let report = check_page(&env, &name, &text, &work);
        eprintln!(
            "{name}: {} run, {} skipped, {} failed",
            report.ran,
            report.skipped.len(),
            report.failures.len()
        );
        ran += report.ran;
        failures.extend(report.failures);
        let _ = std::fs::remove_dir_all(&work);
    }
    assert!(
        failures.is_empty(),
        "stale documentation:\n{}",
        failures.join("\n")
    );
    // The README alone has the demo command and the test command.
    assert!(ran >= 2, "only {ran} blocks found");
}

/// The checker fails on each kind of broken example, and passes the
/// unbroken page the broken ones are made from.
#[test]
fn a_broken_page_fails() {
    let env = Env::new();
    let good = "Text.\n\n\
        <!-- doc-test: parse-only -->\n\
        ```sh\n\
        gazelight run --source pupil://127.0.0.1:50020 --fps 90 \\\n    --headless   # a comment\n\
        ```\n\n\
        <!-- doc-test: config render -->\n\
        ```toml\n\
        [scene]\n\
        view = { yaw_deg = 0.0, pitch_deg = 0.0, hfov_deg = 90.0, width = 64, height = 64 }\n\
        [pipeline]\n\
        glare = { full_weight_deg = 12.0 }\n\
        ```\n\n\
        ```console\n\
        $ gazelight psf --help\n\
        Build one glare point spread function …\n\
        ```\n\n\
        ```csv\n\
        recording,fps\n\
        rec.asc,25\n\
        ```\n\n\
        <!-- doc-test: config layer -->\n\
        ```toml\n\
        effects = \"off\"\n\
        ```\n";
    let work = common::tmp_path("broken");
    let report = check_page(&env, "good.md", good, &work);
    assert!(report.failures.is_empty(), "{:?}", report.failures);
    assert_eq!(report.ran, 5);

    let broken = [
        ("--fps 90", "--fsp 90", "a misspelt flag"),
        ("--fps 90", "--fps -5", "a value out of range"),
        (
            "full_weight_deg = 12.0",
            "window_px = 256",
            "a bad TOML key",
        ),
        ("width = 64", "width = 0", "a view out of range"),
        (
            "gazelight psf --help",
            "gazelite psf --help",
            "an unknown command",
        ),
        ("parse-only", "parse-onyl", "an unknown directive"),
        ("rec.asc,25", "rec.asc,fast", "a bad batch manifest row"),
        (
            "effects = \"off\"",
            "effects = \"maybe\"",
            "a bad layer.toml",
        ),
    ];
    for (from, to, what) in broken {
        assert!(good.contains(from), "{from}");
        let page = good.replacen(from, to, 1);
        let report = check_page(&env, "broken.md", &page, &work);
        assert_eq!(
            report.failures.len(),
            1,
            "{what} must fail exactly one block: {:?}",
            report.failures
        );
    }
    let _ = std::fs::remove_dir_all(&work);
}

#[test]
fn blocks_commands_and_words_are_extracted() {
    let page = "<!-- doc-test: set --frames 2 -->\n```sh\n# a comment\ngazelight render \\\n  --out 'a b'  # why\n\ngazelight psf\n```\n\
        ```text\ngazelight nonsense\n```\n\
        <!-- doc-test: parse-only -->\nA paragraph in between drops it.\n```console\n$ gazelight devices\noutput\n```\n";
    let blocks = extract(page);
    assert_eq!(blocks.len(), 2);
    assert_eq!(blocks[0].directives, vec![vec!["set", "--frames", "2"]]);
    assert!(blocks[1].directives.is_empty());
    assert_eq!(
        commands(&blocks[0]),
        vec!["gazelight render  --out 'a b'", "gazelight psf"]
    );
    assert_eq!(commands(&blocks[1]), vec!["gazelight devices"]);
    assert_eq!(
        words("A=1 gazelight x 'a b' \"c#d\"").unwrap(),
        vec!["A=1", "gazelight", "x", "a b", "c#d"]
    );
    assert_eq!(strip_comment("a 'b # c' # d"), "a 'b # c' ");
}
