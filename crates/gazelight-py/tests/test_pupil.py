"""The pupil light response and the glare kernel from Python, against
Watson & Yellott (2012) written out here from the paper, first-order
dynamics by their definition, and the kernel `gazelight psf` writes."""

import json

import numpy as np
import pytest
from PIL import Image

import gazelight
from conftest import run_cli


def watson_yellott_mm(L, a, age, eyes):
    """W&Y 2012: Stanley & Davies' formula of the effective corneal flux
    F = L·a·M(e) (M(1) = 0.1, M(2) = 1), then the age term of eq. 21."""
    F = L * a * (1.0 if eyes == 2 else 0.1)
    x = (F / 846.0) ** 0.41
    d_sd = 7.75 - 5.75 * x / (x + 2.0)
    return d_sd + (age - 28.58) * (0.02132 - 0.009562 * d_sd)


@pytest.mark.parametrize("L", [0.01, 1.0, 100.0, 10_000.0])
@pytest.mark.parametrize("a,age,eyes", [(1600.0, 28.58, 2), (25.0, 60.0, 2), (400.0, 20.0, 1)])
def test_static_target_is_watson_yellott(L, a, age, eyes):
    m = gazelight.PupilLightResponse(age_years=age)
    assert m.static_mm(L, a, eyes) == pytest.approx(watson_yellott_mm(L, a, age, eyes), abs=1e-9)


def test_a_light_step_gives_latency_then_a_first_order_constriction():
    latency, tau = 0.3, 0.4
    m = gazelight.PupilLightResponse(latency_secs=latency, constriction_tau_secs=tau)
    dt = 0.001
    t = np.arange(0, 9, dt)
    L = np.where(t < 3.0, 1.0, 1000.0)
    a = 1600.0
    p = m.predict(t, L, a)
    age = m.params["age_years"]
    before, after = watson_yellott_mm(1.0, a, age, 2), watson_yellott_mm(1000.0, a, age, 2)
    assert p[t < 3.0 + latency - 2 * dt][-1] == pytest.approx(before, abs=1e-6)
    # One time constant after the delay: 1 − 1/e of the way.
    k = np.searchsorted(t, 3.0 + latency + tau)
    frac = (before - p[k]) / (before - after)
    assert frac == pytest.approx(1 - np.exp(-1), abs=0.01)
    assert p[-1] == pytest.approx(after, abs=1e-3)


def _first_order(t, L, a, age, latency, tau_c, tau_r, scale, offset):
    """The response by its definition: the W&Y target delayed by `latency`,
    approached at tau_c while constricting, tau_r while redilating."""
    target = watson_yellott_mm(np.interp(t - latency, t, L, left=L[0]), a, age, 2)
    p = np.empty_like(t)
    p[0] = target[0]
    for i in range(1, len(t)):
        tau = tau_c if target[i] < p[i - 1] else tau_r
        p[i] = target[i] + (p[i - 1] - target[i]) * np.exp(-(t[i] - t[i - 1]) / tau)
    return scale * p + offset


def test_fit_recovers_an_observer():
    t = np.arange(0, 40, 0.02)
    L = np.where((t % 10 > 5) & (t % 10 < 6), 2000.0, 2.0)  # 1 s flashes every 10 s
    truth = dict(latency=0.28, tau_c=0.35, tau_r=2.0, scale=0.8, offset=0.6)
    pupil = _first_order(t, L, 1600.0, 30.0, truth["latency"], truth["tau_c"], truth["tau_r"],
                         truth["scale"], truth["offset"])
    pupil[(t > 12) & (t < 12.3)] = np.nan  # a blink
    model, fit = gazelight.PupilLightResponse.fit(t, pupil, L, 1600.0, age_years=30.0)
    p = model.params
    assert fit["r_squared"] > 0.99 and fit["rms_mm"] < 0.05
    assert p["latency_secs"] == pytest.approx(truth["latency"], abs=0.03)
    assert p["constriction_tau_secs"] == pytest.approx(truth["tau_c"], rel=0.15)
    assert p["redilation_tau_secs"] == pytest.approx(truth["tau_r"], rel=0.15)
    assert p["scale"] == pytest.approx(truth["scale"], rel=0.05)
    assert p["offset_mm"] == pytest.approx(truth["offset"], abs=0.15)


def test_fit_refuses_too_few_samples():
    t = np.arange(10.0)
    with pytest.raises(gazelight.GazelightError, match="cannot fit"):
        gazelight.PupilLightResponse.fit(t, np.full(10, np.nan), np.ones(10), 100.0)


def test_psf_is_the_cli_kernel(tmp_path, gazelight_bin):
    args = dict(pupil_mm=3.0, ppd=8.0, field_deg=6.0, particles=200, age_years=40.0)
    out = tmp_path / "psf"
    run_cli(gazelight_bin, "psf", "--pupil-mm", "3", "--ppd", "8", "--field-deg", "6", "--particles", "200",
            "--age-years", "40", "--out", str(out))
    facts = json.loads((out / "psf.json").read_text())
    k, info = gazelight.psf(**args)
    assert k.shape == (facts["size"], facts["size"], 3) and k.dtype == np.float32
    assert info["deg_per_px"] == facts["deg_per_px"]
    # Each channel sums to the energy the CLI reports (and to 1).
    np.testing.assert_allclose(k.astype(np.float64).sum(axis=(0, 1)), facts["energy"], rtol=1e-6)
    np.testing.assert_allclose(facts["energy"], 1.0, rtol=1e-3)
    # kernel.png is its log preview: 6 decades below the peak.
    png = np.asarray(Image.open(out / "kernel.png").convert("RGB")).astype(int)
    peak = np.float32(k.max())
    lv = (np.log10(np.maximum(np.maximum(k, 0) / peak, np.float32(1e-12))) + np.float32(6)) / np.float32(6)
    mine = np.round(np.clip(lv, 0, 1) * 255).astype(int)
    diff = np.abs(mine - png)
    assert diff.max() <= 1 and (diff == 0).mean() > 0.999
    # The peak at the centre.
    c = facts["size"] // 2
    assert np.unravel_index(np.argmax(k[..., 1]), k.shape[:2]) == (c, c)
