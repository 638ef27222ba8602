"""gazelight.render against the CLI: the same frames, PNG byte for PNG
byte (gazelight.write_png is the CLI's encoder), and the same timeline rows,
for the embedded demo (`gazelight render`) and for replays of shipped real
recordings (`gazelight replay`); the CLI's error for a recording without
samples; the GIL released while a frame is computed."""

import csv
import socket
import threading
import warnings
import time
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

import gazelight
from conftest import run_cli

# The timeline columns that do not depend on the machine (the `*_ms`
# timings do), with the CSV's decimals (crates/gazelight-output/src/sheet.rs).
DECIMALS = {"gaze_u": 5, "gaze_v": 5, "pupil_mm": 4, "pupil_held": 0, "psf_pupil_mm": 4, "psf_rebuilt": 0,
            "acuity_sigma_px": 3}
RELATIVE = ("target_cd_m2", "adaptation_cd_m2")  # written as {:.6e}


def _timeline(path: Path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def _check_same_frames(cli_out: Path, frames, tmp_path: Path, suffixes=("",)):
    """Each Python frame, encoded with write_png, is the CLI's PNG file
    byte for byte, and decodes to the same pixels; each row is the CLI's
    timeline row to the CSV's precision."""
    rows = _timeline(cli_out / "timeline.csv")
    assert len(frames) == len(rows), (len(frames), len(rows))
    for i, (frame, row) in enumerate(frames):
        cli_png = cli_out / "frames" / f"frame_{i:05d}.png"
        ours = tmp_path / f"py_{i:05d}.png"
        gazelight.write_png(ours, frame)
        assert ours.read_bytes() == cli_png.read_bytes(), f"frame {i}: PNG bytes differ"
        cli_pixels = np.asarray(Image.open(cli_png).convert("RGBA"))
        np.testing.assert_array_equal(frame, cli_pixels, err_msg=f"frame {i}")
        want = rows[i]
        assert row["frame"] == i
        assert abs(row["t_secs"] - float(want["t_secs"])) <= 5.1e-5
        for s in suffixes:
            for col, d in DECIMALS.items():
                got, exp = row[col + s], float(want[col + s])
                assert abs(got - exp) <= 0.51 * 10.0 ** -d + 1e-12, (i, col + s, got, exp)
            for col in RELATIVE:
                got, exp = row[col + s], float(want[col + s])
                assert abs(got - exp) <= 5.1e-7 * abs(exp) + 1e-300, (i, col + s, got, exp)


def test_demo_frames_equal_the_cli_render(gazelight_bin, tmp_path):
    """The embedded default (`gazelight render`: the night scene, the demo
    trace from the ground to the street lamp and back), every 1.5 s of its
    12 s at a reduced size."""
    out = tmp_path / "cli"
    run_cli(gazelight_bin, "render", "--backend", "cpu", "--size", "96x80", "--fps", "0.6667",
            "--out", str(out))
    r = gazelight.render(size=(96, 80), fps=0.6667, backend="cpu")
    assert r.frames >= 8 and r.size == (96, 80)
    frames = list(r)
    assert all(f.shape == (80, 96, 4) and f.dtype == np.uint8 for f, _ in frames)
    # The lamp: the frames differ (the adaptation follows the gaze).
    assert len({f.tobytes() for f, _ in frames}) > 3
    _check_same_frames(out, frames, tmp_path)


# (recording, replay flags, stereo): a Neon recording in stereo, the
# PiPrKit pupil CSV (a recording, not a trace) in mono.
REPLAYS = [
    ("eye/neon-demo", ["--secs", "2", "--fps", "4"], True),
    ("eye/piprkit-plr/pupil_trace.csv", ["--from-secs", "5", "--secs", "3", "--fps", "2"], False),
]


@pytest.mark.parametrize("name,flags,stereo", REPLAYS)
def test_replay_frames_equal_the_cli_replay(name, flags, stereo, data_dir, gazelight_bin, tmp_path):
    path = data_dir / name
    out = tmp_path / "cli"
    run_cli(gazelight_bin, "replay", str(path), "--backend", "cpu", "--size", "48x40", *flags,
            *(["--stereo"] if stereo else []), "--out", str(out))
    kw = dict(zip((f.lstrip("-").replace("-", "_") for f in flags[::2]), (float(v) for v in flags[1::2])))
    r = gazelight.render(None, path, size=(48, 40), stereo=stereo, backend="cpu", **kw)
    frames = list(r)
    assert frames[0][0].shape == (40, 96 if stereo else 48, 4)
    _check_same_frames(out, frames, tmp_path, ("_left", "_right") if stereo else ("",))


def _uniform_hdr(path: Path, w: int = 64, h: int = 32):
    """A Radiance panorama of one colour: RGBE (128, 128, 128, 129), the
    value 1 (1.0039 for readers that add half a step), flat (not run-length)
    scanlines."""
    path.write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n" + f"-Y {h} +X {w}\n".encode()
                     + bytes([128, 128, 128, 129]) * (w * h))


def test_retinal_frames_are_in_cd_m2(tmp_path):
    """retinal=True gives the retinal image (`render --exr`): linear RGB in
    cd/m² before tone mapping. A uniform Radiance scene of value 1 is
    179 cd/m² (Radiance's 179 lm/W white efficacy, its reference manual);
    with glare off the eye's image of a uniform field is that field."""
    scene = tmp_path / "uniform.hdr"
    _uniform_hdr(scene)
    r = gazelight.render(scene, size=(40, 30), frames=2, hfov_deg=30.0, retinal=True,
                         config={"pipeline": {"glare": {"enabled": False}}})
    for img, row in r:
        assert img.shape == (30, 40, 3) and img.dtype == np.float32
        assert np.all(np.abs(img / 179.0 - 1.0) < 0.005), (img.min(), img.max())
        assert abs(row["target_cd_m2"] / 179.0 - 1.0) < 0.01


def test_config_file_is_the_clis(gazelight_bin, tmp_path):
    """The same TOML file through the CLI and Python: the same frames."""
    cfg = tmp_path / "render.toml"
    cfg.write_text("[scene]\nyaw_deg = -70.0\nhfov_deg = 60.0\n\n[pipeline]\nglare = { full_weight_deg = 8.0 }\n\n"
                   "[observer]\nage_years = 70.0\n\n[http]\naddr = \"127.0.0.1:1\"\n")
    out = tmp_path / "cli"
    run_cli(gazelight_bin, "render", "--backend", "cpu", "--size", "64x48", "--frames", "3", "--config", str(cfg),
            "--out", str(out))
    with pytest.warns(gazelight.GazelightWarning, match="http"):
        r = gazelight.render(size=(64, 48), frames=3, config=cfg, backend="cpu")
    _check_same_frames(out, list(r), tmp_path)
    # A bad value: the CLI's words.
    with pytest.raises(gazelight.GazelightError, match="observer.age_years = 400"):
        gazelight.render(config={"observer": {"age_years": 400.0}})


def test_a_config_with_its_scene_and_projection_is_the_clis(gazelight_bin, tmp_path):
    """`scene.file` (relative to the file) and `scene.projection`/`fov_deg`
    from the configuration: Python takes them through the CLI's loader (it
    refused them from a file before, issue 44), so the same frames."""
    study = tmp_path / "study"
    study.mkdir()
    w, h = 64, 32
    pixels = b"".join(bytes([128, 64 + 2 * x, 32 + 4 * y, 126 + (x + y) % 6]) for y in range(h) for x in range(w))
    (study / "gradient.hdr").write_bytes(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n" + f"-Y {h} +X {w}\n".encode() + pixels)
    cfg = study / "study.toml"
    cfg.write_text('[scene]\nfile = "gradient.hdr"\nprojection = "perspective"\nfov_deg = [100.0]\n'
                   "yaw_deg = 5.0\npitch_deg = 0.0\nhfov_deg = 60.0\n")
    out = tmp_path / "cli"
    run_cli(gazelight_bin, "render", "--backend", "cpu", "--size", "48x32", "--frames", "2", "--config", str(cfg),
            "--out", str(out))
    frames = list(gazelight.render(size=(48, 32), frames=2, config=cfg, backend="cpu"))
    _check_same_frames(out, frames, tmp_path)
    # The projection was applied: without it the same picture is an
    # equirectangular panorama and the frame differs.
    cfg.write_text('[scene]\nfile = "gradient.hdr"\nyaw_deg = 5.0\npitch_deg = 0.0\nhfov_deg = 60.0\n')
    plain = list(gazelight.render(size=(48, 32), frames=1, config=cfg))
    assert not np.array_equal(plain[0][0], frames[0][0])
    # A projection without its field: the CLI's words.
    cfg.write_text('[scene]\nfile = "gradient.hdr"\nprojection = "angular"\n')
    with pytest.raises(gazelight.GazelightError, match="--scene-projection angular needs --scene-fov-deg"):
        gazelight.render(size=(48, 32), frames=1, config=cfg)


def _without_samples(data_dir: Path, tmp_path: Path):
    """Recordings that hold no sample: the PiPrKit CSV's header alone, and
    the Neon recording's descriptions with empty streams."""
    csv_path = tmp_path / "header_only.csv"
    csv_path.write_text((data_dir / "eye/piprkit-plr/pupil_trace.csv").read_text().splitlines()[0] + "\n")
    neon = tmp_path / "neon_empty"
    neon.mkdir()
    src = data_dir / "eye/neon-demo"
    for f in src.iterdir():
        if f.suffix in (".json", ".dtype"):
            (neon / f.name).write_bytes(f.read_bytes())
    for stream in ("gaze ps1", "eye_state ps1", "blinks ps1"):
        (neon / f"{stream}.raw").write_bytes(b"")
        (neon / f"{stream}.time").write_bytes(b"")
    return [csv_path, neon]


def _cli_error(p) -> str:
    assert p.returncode != 0, p.stdout
    lines = [l for l in p.stderr.splitlines() if l.startswith("error: ")]
    assert lines, p.stderr
    return lines[-1][len("error: "):]


def test_a_recording_without_samples_raises_the_clis_error(data_dir, gazelight_bin, tmp_path):
    """A recording without samples: the message the CLI prints after
    `error: ` for `replay` (from render) and `inspect` (from read and
    inspect), naming the file and why."""
    for path in _without_samples(data_dir, tmp_path):
        replay = _cli_error(run_cli(gazelight_bin, "replay", str(path), "--backend", "cpu", "--out",
                                    str(tmp_path / "o"), check=False))
        assert "holds no readable samples" in replay and str(path) in replay, replay
        with pytest.raises(gazelight.GazelightError) as e:
            gazelight.render(None, path)
        assert str(e.value) == replay
        inspect = _cli_error(run_cli(gazelight_bin, "inspect", str(path), check=False))
        assert "holds no readable samples" in inspect, inspect
        for f in (gazelight.read, gazelight.inspect):
            with pytest.raises(gazelight.GazelightError) as e, warnings.catch_warnings():
                warnings.simplefilter("ignore", gazelight.GazelightWarning)
                f(path)
            assert str(e.value) == inspect, f


def test_write_png_refuses_a_frame_that_is_not_rgba(tmp_path):
    with pytest.raises(ValueError, match="H×W×4"):
        gazelight.write_png(tmp_path / "x.png", np.zeros((4, 4, 3), np.uint8))


class _Counter:
    """A Python thread that notes the time of each of its iterations (it
    needs the GIL for each)."""

    def __init__(self):
        self.times = []
        self.stop = False
        self.thread = threading.Thread(target=self._run)

    def _run(self):
        while not self.stop:
            self.times.append(time.monotonic())

    def __enter__(self):
        self.thread.start()
        time.sleep(0.05)
        return self

    def __exit__(self, *a):
        self.stop = True
        self.thread.join()

    def largest_gap(self, a, b):
        t = [a] + [x for x in self.times if a <= x <= b] + [b]
        return max(y - x for x, y in zip(t, t[1:]))


def test_render_releases_the_gil_while_a_frame_is_computed():
    """While `next()` renders a frame, another Python thread keeps running:
    it is never kept out for half the call (holding the GIL would keep it
    out for the whole frame, a gap/frame ratio of 1 on every frame).

    How long a frame takes depends on the machine (0.067 s on CI's, 0.3 s
    here), so the test renders frames until it has 0.4 s of them and judges
    the median ratio over the frames long enough to tell (> 20 ms, four of
    Python's 5 ms switch intervals): one frame delayed by the OS scheduler
    cannot fail it, a GIL held through every frame must."""
    r = gazelight.render(size=(1920, 1600), stereo=True, frames=40)
    next(r)  # the first frame builds the kernel
    spans = []
    with _Counter() as c:
        for _ in range(39):
            a = time.monotonic()
            next(r)
            spans.append((a, time.monotonic()))
            if sum(b - a for a, b in spans) > 0.4:
                break
    long_enough = [(a, b) for a, b in spans if b - a > 0.02]
    assert long_enough, f"no frame took over 20 ms: {[round(b - a, 4) for a, b in spans]}"
    ratios = sorted(c.largest_gap(a, b) / (b - a) for a, b in long_enough)
    median = ratios[len(ratios) // 2]
    assert median < 0.5, f"the other thread waited {median:.2f} of a frame (median of {ratios})"


def test_a_waiting_source_releases_the_gil():
    """`next(source)` blocks on a peer that accepts the connection and never
    speaks; another Python thread keeps running meanwhile."""
    with socket.socket() as silent:
        silent.bind(("127.0.0.1", 0))
        silent.listen()
        port = silent.getsockname()[1]
        with gazelight.Source(f"pupil://127.0.0.1:{port}", timeout=1.5) as src, _Counter() as c:
            a = time.monotonic()
            got = next(src, None)
            b = time.monotonic()
    assert got is None, "the silent peer gave a state"
    assert b - a >= 1.0, f"next() returned after {b - a:.3f} s"
    gap = c.largest_gap(a, b)
    assert gap < 0.25 * (b - a), f"the other thread waited {gap:.3f} s of {b - a:.3f} s"
