"""gazelight.trials: the per-trial table of a replay's timeline.csv and
events.csv, against values worked out here by hand and against the CLI's
`gazelight trials` on the same files."""

import csv

import numpy as np
import pytest

import gazelight
from conftest import run_cli


def _write_replay(d):
    """A replay folder written here: 10 fps for 8 s, pupil 4.0 mm with
    +0.5 mm from 1.0 to 2.0 s after an onset at 1.0 s (trial "1", a
    TRIAL_VAR cond=dark) and +0.0 after one at 5.0 s (trial "2",
    cond=bright); one frame without a pupil in the first window."""
    rows = []
    for k in range(80):
        t = k / 10
        pupil = 4.5 if 2.0 <= t < 3.0 else 4.0
        cell = "" if k == 15 else f"{pupil:.3f}"
        residual = "" if k == 15 else f"{pupil - 3.0:.3f}"
        rows.append(f"{t:.3f},{cell},0,3.000,{residual}")
    (d / "timeline.csv").write_text(
        "t_secs,pupil_mm,pupil_held,pupil_light_mm,pupil_residual_mm\n" + "\n".join(rows) + "\n"
    )
    (d / "events.csv").write_text(
        "t_secs,recording_t_secs,t_clock,duration_secs,source,text,trial,frame\n"
        "1.0,1.0,1000,,MSG,stim on,1,10\n"
        "3.5,3.5,3500,,MSG,!V TRIAL_VAR cond dark,1,35\n"
        "5.0,5.0,5000,,MSG,stim on,2,50\n"
        "7.5,7.5,7500,,MSG,!V TRIAL_VAR cond bright,2,75\n"
    )


def test_trials_by_hand_and_as_the_cli(tmp_path, gazelight_bin):
    _write_replay(tmp_path)
    df = gazelight.trials(tmp_path, "stim", baseline=(-0.2, 0.0), window=(0.0, 2.0))
    assert list(df["event"]) == ["stim on", "stim on"]
    assert list(df["var_cond"]) == ["dark", "bright"]
    first, second = df.iloc[0], df.iloc[1]
    assert first["baseline_mm"] == pytest.approx(4.0)
    assert first["peak_dilation_mm"] == pytest.approx(0.5)
    # 20 frames in the window, 19 with a pupil, 10 of them at +0.5.
    assert first["window_frames"] == 20
    assert first["invalid_fraction"] == pytest.approx(0.05, abs=1e-4)
    assert first["mean_dilation_mm"] == pytest.approx(5 / 19, abs=1e-6)
    assert first["residual_dilation_mm"] == pytest.approx(5 / 19, abs=1e-6)
    assert first["pupil_light_mean_mm"] == pytest.approx(3.0)
    assert second["peak_dilation_mm"] == pytest.approx(0.0)
    assert bool(first["valid"]) and bool(second["valid"])

    out = tmp_path / "cli.csv"
    run_cli(gazelight_bin, "trials", str(tmp_path), "--events", "stim", "--baseline", "-0.2..0",
            "--window", "0..2", "--out", str(out))
    with open(out, newline="") as f:
        cli = list(csv.DictReader(f))
    assert len(cli) == len(df)
    for row, (_, py) in zip(cli, df.iterrows()):
        for col in ("baseline_mm", "peak_dilation_mm", "mean_dilation_mm", "residual_dilation_mm"):
            assert float(row[col]) == pytest.approx(float(py[col]), abs=1e-9)
        assert row["var_cond"] == py["var_cond"]


def test_no_matching_event_is_an_error(tmp_path):
    _write_replay(tmp_path)
    with pytest.raises(gazelight.GazelightError, match="no event matches"):
        gazelight.trials(tmp_path, "nothing")
    with pytest.raises(gazelight.GazelightError, match="--window"):
        gazelight.trials(tmp_path, "stim", window=(3.0, 1.0))
    assert np.isfinite(0.0)
