//! The official BIDS validator (`bids-validator-deno`, from PyPI, installed
//! by `.ci/test`) run on a dataset a test wrote.

use std::path::Path;
use std::process::Command;

/// Runs `bids-validator-deno --format json` on `root` and fails the test
/// on any error it reports; prints the error and warning counts. Outside CI
/// a missing validator prints `SKIP` and returns ([`crate::skip_or_fail`]).
pub fn validate(root: &Path) {
    let out = match Command::new("bids-validator-deno")
        .arg("--format")
        .arg("json")
        .arg(root)
        .output()
    {
        Ok(o) => o,
        Err(e) => {
            crate::skip_or_fail(&format!(
                "bids-validator-deno not runnable ({e}; pip install bids-validator-deno)"
            ));
            return;
        }
    };
    let report: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap_or_else(|e| {
        panic!(
            "validator output is not JSON ({e}): {}",
            String::from_utf8_lossy(&out.stderr)
        )
    });
    let issues = report["issues"]["issues"]
        .as_array()
        .cloned()
        .unwrap_or_default();
    let of = |severity: &str| -> Vec<String> {
        issues
            .iter()
            .filter(|i| i["severity"] == severity)
            .map(|i| format!("{} {} {}", i["code"], i["subCode"], i["location"]))
            .collect()
    };
    let (errors, warnings) = (of("error"), of("warning"));
    eprintln!(
        "bids-validator-deno {} (schema {}): {} errors, {} warnings {warnings:?}",
        root.display(),
        report["summary"]["schemaVersion"],
        errors.len(),
        warnings.len()
    );
    assert!(errors.is_empty(), "{}: {errors:#?}", root.display());
}
