"""Shared fixtures: the CLI binary the parity tests compare with, and the
shared real recordings (found as gazelight-test-support's data.rs finds
them: GAZELIGHT_DATA_DIR, else shared/data beside the workspace root).

Outside CI a missing binary or data directory skips; with CI set it fails.
"""

import json
import os
import subprocess
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent


def _workspace_root(start: Path) -> Path:
    for d in [start, *start.parents]:
        toml = d / "Cargo.toml"
        if toml.is_file() and any(l.strip() == "[workspace]" for l in toml.read_text().splitlines()):
            return d
    raise RuntimeError(f"no workspace Cargo.toml above {start}")


ROOT = _workspace_root(HERE)

# The shared recordings every front end must agree on.
RECORDINGS = ["eye/neon-demo", "eye/eyelink-psa/both_eyes.asc", "eye/piprkit-plr/pupil_trace.csv"]


def _missing(what: str):
    if os.environ.get("CI"):
        pytest.fail(f"{what} (CI is set: a missing tool fails)")
    pytest.skip(what)


@pytest.fixture(scope="session")
def data_dir() -> Path:
    env = os.environ.get("GAZELIGHT_DATA_DIR")
    d = Path(env) if env else ROOT.parent / "shared" / "data"
    if not d.is_dir():
        _missing(f"the shared test data directory {d} does not exist; set GAZELIGHT_DATA_DIR")
    return d


@pytest.fixture(scope="session")
def gazelight_bin() -> Path:
    env = os.environ.get("GAZELIGHT_BIN")
    target = Path(os.environ.get("CARGO_TARGET_DIR", ROOT / "target"))
    b = Path(env) if env else target / "debug" / "gazelight"
    if not b.is_file():
        _missing(f"the gazelight CLI {b} is not built (cargo build -p gazelight)")
    return b


def run_cli(binary: Path, *args: str, check: bool = True) -> subprocess.CompletedProcess:
    p = subprocess.run([str(binary), *args], capture_output=True, text=True, timeout=600)
    if check and p.returncode != 0:
        raise AssertionError(f"gazelight {' '.join(args)} failed ({p.returncode}):\n{p.stderr}")
    return p


def inspect_json(binary: Path, path: Path) -> dict:
    return json.loads(run_cli(binary, "inspect", "--json", str(path)).stdout)
