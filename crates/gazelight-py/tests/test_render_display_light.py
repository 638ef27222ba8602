"""gazelight.render(recording, display_light=...) against `gazelight replay
--display-light`: a screen experiment written here (a CSV recording and its
Cloud-style events.csv, trials alternating between a 2 and a 100 cd/m^2
display, the test eye's pupil a first-order response between 6.0 and
3.6 mm): the light-driven pupil of every row equals the CLI's, the dark
trials' settled light-driven pupil is larger than the bright ones', a
``pupil_fit`` block fitted on the display's light gives the CLI's fitted
parameters and sits on the eye's own pupils, and the geometry arguments
are checked."""

import csv
import math
from pathlib import Path

import pytest

import gazelight
from conftest import run_cli

TRIAL_SECS = 8.0
TRIALS = 6
RATE_HZ = 100.0
DARK_CD_M2, BRIGHT_CD_M2 = 2.0, 100.0
DARK_MM, BRIGHT_MM = 6.0, 3.6
LATENCY_S, TAU_C_S, TAU_D_S = 0.25, 0.4, 1.2
# timeline.csv's 4 decimals.
TOL_MM = 0.51e-4 + 1e-9


def _experiment(d: Path) -> Path:
    d.mkdir()
    t0_ns = 1_700_000_000_000_000_000
    rows = ["timestamp [ns],gaze_u,gaze_v,pupil_mm"]
    light = DARK_MM
    dt = 1.0 / RATE_HZ
    for i in range(int(TRIALS * TRIAL_SECS * RATE_HZ)):
        t = i * dt
        lit = min(int(max(t - LATENCY_S, 0.0) / TRIAL_SECS), TRIALS - 1)
        target = DARK_MM if lit % 2 == 0 else BRIGHT_MM
        tau = TAU_C_S if target < light else TAU_D_S
        light += (target - light) * (1.0 - math.exp(-dt / tau))
        rows.append(f"{t0_ns + round(t * 1e9)},0.5,0.5,{light:.4f}")
    (d / "gaze.csv").write_text("\n".join(rows) + "\n")
    ev = ["timestamp [ns],name"]
    for k in range(TRIALS):
        ev.append(f"{t0_ns + int(k * TRIAL_SECS * 1e9)},light {'dark' if k % 2 == 0 else 'bright'} {k}")
    (d / "events.csv").write_text("\n".join(ev) + "\n")
    return d / "gaze.csv"


def _display(tmp_path: Path) -> Path:
    p = tmp_path / "display.csv"
    p.write_text(f"event,luminance_cd_m2\nlight dark*,{DARK_CD_M2}\nlight bright*,{BRIGHT_CD_M2}\n")
    return p


NOGLARE = {"pipeline": {"glare": {"enabled": False}}}


def test_display_light_rows_equal_the_cli_and_follow_the_display(gazelight_bin, tmp_path):
    rec = _experiment(tmp_path / "rec")
    display = _display(tmp_path)
    cfg = tmp_path / "noglare.toml"
    cfg.write_text("[pipeline]\nglare = { enabled = false }\n")
    out = tmp_path / "cli"
    p = run_cli(gazelight_bin, "replay", str(rec), "--size", "32x24", "--fps", "10", "--no-frames",
                "--backend", "cpu", "--config", str(cfg), "--display-light", str(display),
                "--display-deg", "40x30", "--pupil-fit", "7..24", "--out", str(out))
    with open(out / "timeline.csv", newline="") as f:
        want = list(csv.DictReader(f))
    r = gazelight.render(None, rec, size=(32, 24), fps=10, config=NOGLARE, images=False,
                         display_light=display, display_deg=(40, 30), pupil_fit=(7, 24))
    got = [row for _, row in r]
    assert len(got) == len(want)
    for i, (g, w) in enumerate(zip(got, want)):
        for c in ("pupil_light_mm", "pupil_residual_mm"):
            assert abs(g[c] - float(w[c])) <= TOL_MM, (i, c, g[c], w[c])
    # The fit's parameters: the CLI's printed ones, and the eye's own
    # dynamics (fitted on the display's light).
    (params,) = r.pupil_light_params
    assert params["source"] == "fit"
    assert f"latency {params['latency_secs']:.3f} s" in p.stdout, (params, p.stdout)
    assert abs(params["latency_secs"] - LATENCY_S) < 0.03, params
    assert abs(params["constriction_tau_secs"] / TAU_C_S - 1) < 0.1, params
    assert abs(params["redilation_tau_secs"] / TAU_D_S - 1) < 0.1, params
    # Settled (the last 2 s of each trial): the light-driven pupil on the
    # eye's dark and bright pupils.
    for g in got:
        t = g["t_secs"]
        k = int(t // TRIAL_SECS)
        if k < TRIALS and t - k * TRIAL_SECS >= TRIAL_SECS - 2.0:
            want_mm = DARK_MM if k % 2 == 0 else BRIGHT_MM
            assert abs(g["pupil_light_mm"] - want_mm) < 0.1, (t, g["pupil_light_mm"], want_mm)


def test_display_geometry_is_checked(tmp_path):
    rec = _experiment(tmp_path / "rec")
    display = _display(tmp_path)
    with pytest.raises(gazelight.GazelightError, match="display_cm and viewing_distance_cm go together"):
        gazelight.render(None, rec, display_light=display, display_cm=(52, 29))
    with pytest.raises(gazelight.GazelightError, match="give display_light"):
        gazelight.render(None, rec, display_deg=(40, 30))
    with pytest.raises(gazelight.GazelightError, match="not a trace"):
        gazelight.render(None, None, display_light=display)
    # By size and distance: accepted.
    r = gazelight.render(None, rec, size=(32, 24), fps=2, frames=3, images=False,
                         display_light=display, display_cm=(52, 29), viewing_distance_cm=60)
    assert len(list(r)) == 3
