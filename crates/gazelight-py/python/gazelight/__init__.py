"""gazelight from Python.

The same library code as the ``gazelight`` CLI (the importers, the filter
chain, calibration profiles), with numpy arrays out:

- :func:`read` -- a recording (Pupil Core directory, Neon, EyeLink ``.asc``, XDF, BIDS,
  pupil ``.csv``, and every format ``gazelight inspect`` reads) through the
  filter chain, as per-eye arrays (or a pandas DataFrame), with its events
  (``rec.events``: EyeLink messages and trials, XDF markers, Pupil
  annotations, Neon events, BIDS events);
- :class:`FilterChain` -- the chain itself, sample by sample or over arrays;
- :class:`Calibration` -- a calibration profile (raw tracker units -> mm);
- :class:`PupilLightResponse` -- the pupil's light response (W&Y target,
  latency, constriction/redilation) and its fit on a recording's block;
- :class:`Source` -- a live source (``pupil://``, ``neon://``, ``lsl://``,
  ...) as a context manager yielding :class:`EyeState` as they arrive;
- :func:`psf` -- the glare kernel ``gazelight psf`` builds, as an array;
- :func:`render` -- a scene and a trace or a recording -> frames, one at a
  time, with their ``timeline.csv`` rows (the CLI's ``render``/``replay``);
  :func:`write_png` writes a frame with the CLI's PNG encoder;
- :class:`GazelightError` -- what the CLI would report, with its message.

Eye indices follow Pupil Core: 0 is the right eye, 1 the left eye.
"""

from __future__ import annotations

import json
import os
import warnings
from dataclasses import dataclass, field
from typing import Any, Dict, List, Optional, Tuple, Union

import numpy as np

from ._gazelight import (  # noqa: F401
    Calibration,
    EyeState,
    FilterChain,
    GazelightError,
    PupilLightResponse,
    Render,
    Source,
    input_kind as _input_kind,
    inspect_json as _inspect_json,
    psf,
    read_config_text as _read_config_text,
    read_recording as _read_recording,
    render_open as _render_open,
    trials_csv as _trials_csv,
    write_png,
)

__all__ = [
    "Calibration",
    "Eye",
    "EyeState",
    "Events",
    "FilterChain",
    "Gaze",
    "GazelightError",
    "GazelightWarning",
    "PupilLightResponse",
    "Recording",
    "Render",
    "Source",
    "check_render",
    "inspect",
    "psf",
    "read",
    "render",
    "trials",
    "write_png",
]

PathLike = Union[str, "os.PathLike[str]"]


class GazelightWarning(UserWarning):
    """A recording's warning (a skipped record, a missing file beside it, ...)."""


@dataclass(frozen=True)
class Eye:
    """One eye's pupil samples, one row per sample, in recording order.

    ``t_secs``: the sample's time (s, the recording's clock);
    ``pupil_raw``: the diameter as the tracker reported it, in ``unit``;
    ``tracker_mm``: the tracker's own mm (3D model, Neon), NaN when none;
    ``pupil_mm``: the measured pupil in mm -- the sample's own value when
    it is clean and in mm (the tracker's mm, or raw x a physical scale),
    NaN otherwise (lost, within 50 ms of a blink, a speed outlier, or a
    raw unit with no physical scale);
    ``measured_value``: the measured pupil of clean samples in
    ``measured_unit`` (the raw unit where no physical scale is known), NaN
    otherwise; ``interpolated``: ``measured_value`` with the discarded
    stretches up to 1 s bridged by straight lines (Kret & Sjak-Shie 2019;
    MNE's ``interpolate_blinks``), marked in ``is_interpolated``;
    ``aperture_mm``: the model aperture the glare PSF is built for (001
    section 5's black/white map, held through blinks) -- not a measurement;
    ``fate``: what the guideline cleaning made of the sample (``fates``:
    clean, lost, out_of_range, margin, speed, other_stream);
    ``confidence``: the tracker's confidence (0..1);
    ``blink``: the chain considers the eye closed;
    ``dropout``: the chain rejected this sample (low confidence, no pupil,
    out of range, too fast) -- the ``dropout_fraction`` of ``inspect``;
    ``measured``: accepted as a measurement; ``origin``: where
    ``aperture_mm`` came from (``origins``: measured, held, model, default);
    ``settling``: the output still moves to its target at the rate limit;
    ``detector``: index into ``detectors`` (``2d``, ``3d``, ``pupil``).
    """

    eye: int
    t_secs: np.ndarray
    pupil_raw: np.ndarray
    unit_code: np.ndarray
    tracker_mm: np.ndarray
    pupil_mm: np.ndarray
    measured_value: np.ndarray
    measured_unit_code: np.ndarray
    interpolated: np.ndarray
    is_interpolated: np.ndarray
    aperture_mm: np.ndarray
    fate: np.ndarray
    confidence: np.ndarray
    detector: np.ndarray
    origin: np.ndarray
    outcome: np.ndarray
    blink: np.ndarray
    settling: np.ndarray
    units: Tuple[str, ...]
    detectors: Tuple[str, ...]
    origins: Tuple[str, ...]
    fates: Tuple[str, ...] = ()

    @property
    def dropout(self) -> np.ndarray:
        """The samples the chain rejected (boolean)."""
        return self.outcome == 1

    @property
    def measured(self) -> np.ndarray:
        """The samples the chain accepted as measurements (boolean)."""
        return self.outcome == 0

    @property
    def unit(self) -> Optional[str]:
        """The unit of the first sample's raw pupil (as ``inspect``), or None."""
        if len(self.unit_code) == 0:
            return None
        return self.units[int(self.unit_code[0])]

    def __len__(self) -> int:
        return len(self.t_secs)


@dataclass(frozen=True)
class Gaze:
    """Gaze samples: normalised image coordinates (top-left origin).

    ``eyes``: 0 binocular, 1 right eye only, 2 left eye only;
    ``filtered_u``/``filtered_v``: the chain's fused gaze after the sample.
    """

    t_secs: np.ndarray
    u: np.ndarray
    v: np.ndarray
    confidence: np.ndarray
    eyes: np.ndarray
    filtered_u: np.ndarray
    filtered_v: np.ndarray
    filtered_valid: np.ndarray

    def __len__(self) -> int:
        return len(self.t_secs)


@dataclass(frozen=True)
class Events:
    """A recording's events (EyeLink ``MSG`` lines, XDF marker streams,
    Pupil annotations, Neon events, BIDS physioevents and ``_events.tsv``),
    sorted by time; see docs/events.md.

    ``t_secs``: on the clock the recording's samples use (``Eye.t_secs``);
    ``t_clock``: on the recording's own clock, in :attr:`clock`'s unit;
    ``duration_secs``: NaN where the recording gives none; ``text`` and
    ``source`` (``MSG``, an XDF stream's name, ``annotation``, ``event``,
    ``physioevents``, ``events``) as lists of str; ``trial``: an index into
    :attr:`trials` (-1: none). ``trials``: EyeLink's ``TRIALID`` ..
    ``TRIAL_RESULT`` spans as dicts (``id``, ``start_t_secs``,
    ``end_t_secs``, ``result``, ``vars``: the ``!V TRIAL_VAR`` values).
    ``dropped``: events past the import's bound, counted, not kept.
    """

    t_secs: np.ndarray
    t_clock: np.ndarray
    duration_secs: np.ndarray
    text: List[str]
    source: List[str]
    trial: np.ndarray
    trials: List[Dict[str, Any]]
    clock: str
    dropped: int = 0
    truncated: int = 0

    def __len__(self) -> int:
        return len(self.t_secs)

    def to_dataframe(self):
        """The events as a pandas DataFrame: ``t_secs``, ``t_clock``,
        ``duration_secs``, ``source``, ``text``, ``trial`` (the trial's
        id, None outside trials) and one column per trial variable; needs
        pandas."""
        try:
            import pandas as pd
        except ImportError as e:  # pragma: no cover - depends on the env
            raise ImportError("Events.to_dataframe needs pandas (pip install pandas)") from e
        trial_ids = [t["id"] for t in self.trials]
        cols: Dict[str, Any] = {
            "t_secs": self.t_secs,
            "t_clock": self.t_clock,
            "duration_secs": self.duration_secs,
            "source": pd.Categorical(self.source),
            "text": list(self.text),
            "trial": [trial_ids[k] if k >= 0 else None for k in self.trial],
        }
        names: List[str] = []
        for t in self.trials:
            names.extend(n for n in t["vars"] if n not in names)
        for n in names:
            cols[n] = [self.trials[k]["vars"].get(n) if k >= 0 else None for k in self.trial]
        return pd.DataFrame(cols)


def _events(d: Dict[str, Any]) -> Events:
    return Events(
        t_secs=d["t_secs"],
        t_clock=d["t_clock"],
        duration_secs=d["duration_secs"],
        text=list(d["text"]),
        source=list(d["source"]),
        trial=d["trial"],
        trials=list(d["trials"]),
        clock=d["clock"],
        dropped=int(d["dropped"]),
        truncated=int(d["truncated"]),
    )


@dataclass(frozen=True)
class Recording:
    """A recording read through the filter chain (see :func:`read`).

    Its times are on the recording's clock (see :attr:`first_sample_secs`).
    """

    path: str
    format: str
    eyes: Tuple[Eye, Eye]
    gaze: Gaze
    recording_blinks: Dict[str, np.ndarray]
    closures: Dict[str, np.ndarray]
    stats: Dict[str, Any]
    warnings: List[str]
    skipped_records: int
    eye_gaze: Optional[Dict[str, Any]] = field(default=None)
    events: Optional[Events] = field(default=None)
    """The recording's events (:class:`Events`; ``events.to_dataframe()``)."""

    @property
    def first_sample_secs(self) -> Optional[float]:
        """The first sample's time (s), or None without samples.

        Every time of a :class:`Recording` (``Eye.t_secs``, ``Gaze.t_secs``,
        blinks, ``events.t_secs``) is on the recording's clock, as ``gazelight
        inspect`` prints them (``inspect``'s ``first_sample_secs`` is this
        value). :func:`render` rows and the CLI's ``timeline.csv`` count
        seconds from the first frame instead: their ``t_secs`` +
        ``first_sample_secs`` + ``from_secs`` is the recording's time (the
        replay's ``session.json`` names it
        ``time.first_frame_recording_secs``).
        """
        firsts = [float(np.min(a)) for a in (self.eyes[0].t_secs, self.eyes[1].t_secs, self.gaze.t_secs) if len(a)]
        return min(firsts) if firsts else None

    @property
    def right(self) -> Eye:
        return self.eyes[0]

    @property
    def left(self) -> Eye:
        return self.eyes[1]

    def blinks(self, eye: int) -> Tuple[np.ndarray, np.ndarray]:
        """The chain's blinks of ``eye``: (start_t_secs, end_t_secs)."""
        c = self.closures
        sel = (c["eye"] == eye) & c["blink"]
        return c["start_t_secs"][sel], c["end_t_secs"][sel]

    def dropouts(self, eye: int) -> Tuple[np.ndarray, np.ndarray]:
        """Closures of ``eye`` too short or too long to be blinks."""
        c = self.closures
        sel = (c["eye"] == eye) & ~c["blink"]
        return c["start_t_secs"][sel], c["end_t_secs"][sel]

    def to_dataframe(self):
        """The pupil samples of both eyes as one pandas DataFrame (long form:
        a column ``eye``), sorted by time; needs pandas."""
        try:
            import pandas as pd
        except ImportError as e:  # pragma: no cover - depends on the env
            raise ImportError("Recording.to_dataframe needs pandas (pip install pandas)") from e
        frames = []
        for e in self.eyes:
            frames.append(
                pd.DataFrame(
                    {
                        "eye": np.full(len(e), e.eye, dtype=np.uint8),
                        "t_secs": e.t_secs,
                        "pupil_raw": e.pupil_raw,
                        "unit": pd.Categorical.from_codes(e.unit_code, categories=list(e.units)),
                        "tracker_mm": e.tracker_mm,
                        "pupil_mm": e.pupil_mm,
                        "measured_value": e.measured_value,
                        "measured_unit": pd.Categorical.from_codes(e.measured_unit_code, categories=list(e.units)),
                        "interpolated": e.interpolated,
                        "is_interpolated": e.is_interpolated,
                        "aperture_mm": e.aperture_mm,
                        "fate": pd.Categorical.from_codes(
                            np.where(e.fate == 255, -1, e.fate).astype(np.int16), categories=list(e.fates)
                        ),
                        "confidence": e.confidence,
                        "detector": pd.Categorical.from_codes(e.detector, categories=list(e.detectors)),
                        "origin": pd.Categorical.from_codes(e.origin, categories=list(e.origins)),
                        "blink": e.blink,
                        "dropout": e.dropout,
                        "settling": e.settling,
                    }
                )
            )
        df = pd.concat(frames, ignore_index=True)
        return df.sort_values(["t_secs", "eye"], kind="stable", ignore_index=True)


def read(
    path: PathLike,
    config: Union[None, str, Dict[str, Any]] = None,
    calibration: Union[None, PathLike, Calibration] = None,
    dataframe: bool = False,
):
    """Reads a recording through the filter chain, as ``gazelight inspect``
    and ``replay`` do.

    ``path``: a Neon or Pupil Core recording directory, an EyeLink ``.asc``,
    a pupil ``.csv`` (any recording the CLI reads). ``config``: the filter
    chain's configuration (a dict or TOML text with the keys of the CLI
    configuration's ``[filter]`` table; None for the defaults).
    ``calibration``: a calibration profile (path or :class:`Calibration`)
    mapping raw tracker units onto mm. ``dataframe=True`` returns
    :meth:`Recording.to_dataframe` instead of the :class:`Recording`.

    The recording's warnings are issued as :class:`GazelightWarning`.
    Raises :class:`GazelightError` with the CLI's message when the file
    cannot be read, ``TypeError`` for an argument of the wrong type.
    """
    d = _read_recording(path, config, calibration)
    eyes = tuple(
        Eye(
            eye=i,
            t_secs=e["t_secs"],
            pupil_raw=e["pupil_raw"],
            unit_code=e["unit"],
            tracker_mm=e["tracker_mm"],
            pupil_mm=e["pupil_mm"],
            measured_value=e["measured"],
            measured_unit_code=e["measured_unit"],
            interpolated=e["interpolated"],
            is_interpolated=e["is_interpolated"],
            aperture_mm=e["aperture_mm"],
            fate=e["fate"],
            confidence=e["confidence"],
            detector=e["detector"],
            origin=e["origin"],
            outcome=e["outcome"],
            blink=e["blink"],
            settling=e["settling"],
            units=tuple(d["units"]),
            detectors=tuple(d["detectors"]),
            origins=tuple(d["origins"]),
            fates=tuple(d["fates"]),
        )
        for i, e in enumerate(d["eyes"])
    )
    rec = Recording(
        path=os.fspath(d["path"]),
        format=d["format"],
        eyes=eyes,  # type: ignore[arg-type]
        gaze=Gaze(**d["gaze"]),
        recording_blinks=d["recording_blinks"],
        closures=d["closures"],
        stats=json.loads(d["stats"]),
        warnings=list(d["warnings"]),
        skipped_records=int(d["skipped_records"]),
        eye_gaze=json.loads(d["eye_gaze"]) if d["eye_gaze"] else None,
        events=_events(d["events"]),
    )
    for w in rec.warnings:
        warnings.warn(GazelightWarning(f"{rec.path}: {w}"), stacklevel=2)
    return rec.to_dataframe() if dataframe else rec


def inspect(
    path: PathLike,
    config: Union[None, str, Dict[str, Any]] = None,
    calibration: Union[None, PathLike, Calibration] = None,
) -> Dict[str, Any]:
    """The summary ``gazelight inspect --json`` prints for a recording, as a dict.

    The warnings ``inspect`` prints (the summary's ``warnings``: skipped
    records, pupils nearly all rejected, a pupil in raw units with no
    physical scale) are issued as :class:`GazelightWarning`, as ``read`` does.
    """
    summary = json.loads(_inspect_json(path, config, calibration))
    for w in summary.get("warnings", []):
        warnings.warn(GazelightWarning(f"{os.fspath(path)}: {w}"), stacklevel=2)
    return summary


def _is_trace(path: PathLike) -> bool:
    # Decided natively with the bounded opener: a FIFO or a device raises
    # GazelightError instead of blocking or being read without end, and
    # only the first MiB of a `.csv` is read to find its header.
    return _input_kind(os.fspath(path)) == "trace"



def _config_name(config) -> Optional[str]:
    """The path of a ``config`` that names a file (a path, or a string of
    one line naming a file that exists), else None."""
    if isinstance(config, os.PathLike) or (isinstance(config, str) and "\n" not in config and os.path.isfile(config)):
        return os.fspath(config)
    return None


def _render_inputs(scene, trace_or_recording, config):
    """``render``'s positional inputs for the native half, and the config:
    a file's text (read with the bounded reader: a regular file, at most 1
    MiB, structure checked, as the CLI reads its config) with its name, a
    TOML string or a dict as given."""
    config_name = _config_name(config)
    if config_name is not None:
        config = _read_config_text(config_name)
    trace = recording = None
    if trace_or_recording is not None:
        if _is_trace(trace_or_recording):
            trace = os.fspath(trace_or_recording)
        else:
            recording = os.fspath(trace_or_recording)
    return dict(
        scene=None if scene is None else os.fspath(scene),
        trace=trace,
        recording=recording,
        config=config,
        config_name=config_name,
    )


def _fit_range(pupil_fit):
    if isinstance(pupil_fit, (tuple, list)):
        if len(pupil_fit) != 2:
            raise ValueError(f"pupil_fit: expected \"FROM..TO\" or (FROM, TO), got {pupil_fit!r}")
        return f"{pupil_fit[0]}..{pupil_fit[1]}"
    return pupil_fit


def render(
    scene: Optional[PathLike] = None,
    trace_or_recording: Optional[PathLike] = None,
    *,
    size: Optional[Tuple[int, int]] = None,
    stereo: bool = False,
    config: Union[None, PathLike, str, Dict[str, Any]] = None,
    fps: float = 30.0,
    frames: Optional[int] = None,
    retinal: bool = False,
    calibration: Optional[PathLike] = None,
    from_secs: float = 0.0,
    secs: Optional[float] = None,
    yaw_deg: Optional[float] = None,
    pitch_deg: Optional[float] = None,
    hfov_deg: Optional[float] = None,
    luminance_scale: Optional[float] = None,
    pupil_fit: Union[None, str, Tuple[float, float]] = None,
    pupil_black_cd_m2: Optional[float] = None,
    pupil_white_cd_m2: Optional[float] = None,
    images: bool = True,
    backend: str = "auto",
    display_light: Optional[PathLike] = None,
    display_deg: Union[None, str, Tuple[float, float]] = None,
    display_cm: Union[None, str, Tuple[float, float]] = None,
    viewing_distance_cm: Optional[float] = None,
) -> Render:
    """Render frames as ``gazelight render`` (a trace) or ``gazelight
    replay`` (a recording) does, one at a time: an iterator of
    ``(frame, row)``.

    ``frame`` is the display image as an H x W x 4 ``uint8`` array (RGBA;
    stereo: left | right side by side), the pixels the CLI writes as
    ``frames/frame_NNNNN.png`` (:func:`write_png` writes the same bytes);
    with ``retinal=True`` it is the retinal image instead, H x W x 3
    ``float32``, linear RGB in cd/m^2 after glare and acuity (NaN where the
    view has no data; the CLI's ``--exr`` frames). ``row`` is the frame's
    row of ``timeline.csv`` as a dict with the same column names
    (``t_secs``, ``gaze_u``, ``pupil_mm``, ... with ``_left``/``_right``
    in stereo), unrounded, plus ``frame`` (the index). A recording's rows
    also have ``replay``'s pupil light response: ``pupil_light_mm`` (the
    pupil the light predicts) and ``pupil_residual_mm`` (measured minus
    predicted; NaN where the pupil is not measured, an empty cell in the
    CLI's CSV), per view.

    ``scene``: an HDR panorama (OpenEXR or Radiance), default the embedded
    night scene. ``trace_or_recording``: a trace CSV
    (``t_secs,gaze_u,gaze_v,pupil_mm[,confidence]``) or any recording
    ``gazelight replay`` reads (Neon or Pupil Core directory, EyeLink
    ``.asc``, pupil ``.csv``, ...); default the demo trace on the embedded
    scene, a slow gaze sweep on a scene of your own. ``config``: the CLI's
    TOML configuration (a path, a TOML string or a dict), loaded and
    checked by the CLI's own loader: its ``[pipeline]``, ``[filter]``,
    ``[observer]``, ``scene.file``, ``scene.luminance_scale``,
    ``scene.projection``/``fov_deg``, the view (``scene.yaw_deg``,
    ``pitch_deg``, ``hfov_deg``, ``view``), ``display.size`` and, for a
    recording, ``source.calibration``; keyword arguments override it. The
    frames are
    rendered on the CPU pipeline (``--backend cpu``), with the GIL
    released; a recording is streamed, never loaded whole.

    The pupil light response of a recording (``replay``'s options):
    ``pupil_fit`` fits the observer on a baseline block first, ``"FROM..TO"``
    or ``(FROM, TO)`` in seconds from the recording's first sample
    (``--pupil-fit``); ``pupil_black_cd_m2`` and ``pupil_white_cd_m2`` are
    the display's luminances when the ``calibration`` profile was made
    (``--pupil-black-cd-m2``, ``--pupil-white-cd-m2``; default 0.1 and 100).
    Each view's parameters and where they came from:
    :attr:`Render.pupil_light_params`.

    ``images=False``: only the rows, without the image pipeline (the CLI's
    ``--no-frames`` path; ``frame`` is ``None``): the same values, the
    stage timings (``pooling_ms`` ... ``total_ms``) NaN; thousands of frames
    a second on one core instead of tens (docs/replay.md, "Analysis at
    study speed"). Not with ``retinal=True``.

    ``backend``: the frame pipeline, chosen as the CLI's ``--backend``
    chooses (the same rule, in the application core): ``"auto"`` (the
    default, as the CLI's) a hardware GPU when there is one, else the CPU
    pipeline (a software adapter such as lavapipe runs on the same cores and
    is slower than the CPU pipeline, so ``auto`` does not pick it);
    ``"gpu"`` the GPU pipeline on the best adapter, a software one included,
    and a :class:`GazelightError` when there is none; ``"cpu"`` the CPU
    reference pipeline. The two pipelines' frames agree within 1/255.
    :attr:`Render.backend` names the pipeline chosen and
    :attr:`Render.backend_reason` why (``None`` with ``images=False``).

    ``display_light``: a recording's pupil light response driven by the
    display's light instead of the scene's (``replay --display-light``): a
    CSV of ``t_secs,luminance_cd_m2`` (seconds from the first sample) or
    ``event,luminance_cd_m2`` (an event pattern of the recording's events),
    with the display's size as ``display_deg`` (``(W, H)`` degrees or
    ``"WxH"``; default 40 x 30) or ``display_cm`` at
    ``viewing_distance_cm``. A ``pupil_fit`` block then sees the display's
    light too (docs/screen-experiment.md).
    """
    r = _render_open(
        **_render_inputs(scene, trace_or_recording, config),
        size=None if size is None else (int(size[0]), int(size[1])),
        stereo=stereo,
        fps=fps,
        frames=frames,
        retinal=retinal,
        calibration=None if calibration is None else os.fspath(calibration),
        from_secs=from_secs,
        secs=secs,
        yaw_deg=yaw_deg,
        pitch_deg=pitch_deg,
        hfov_deg=hfov_deg,
        luminance_scale=luminance_scale,
        pupil_fit=_fit_range(pupil_fit),
        pupil_black_cd_m2=pupil_black_cd_m2,
        pupil_white_cd_m2=pupil_white_cd_m2,
        images=images,
        backend=backend,
        display_light=None if display_light is None else os.fspath(display_light),
        display_deg=_wxh(display_deg),
        display_cm=_wxh(display_cm),
        viewing_distance_cm=viewing_distance_cm,
    )
    config_name = _config_name(config)
    where = f"config {config_name}" if config_name else "config"
    for key in r.ignored:
        warnings.warn(GazelightWarning(f"{where}: `{key}` does not apply to gazelight.render; ignored"), stacklevel=2)
    for w in r.warnings:
        warnings.warn(GazelightWarning(w), stacklevel=2)
    return r


def _wxh(v: Union[None, str, Tuple[float, float]]) -> Optional[str]:
    """``(W, H)`` or ``"WxH"`` as the CLI's ``WxH``."""
    if v is None or isinstance(v, str):
        return v
    w, h = v
    return f"{float(w)!r}x{float(h)!r}"


def check_render(
    scene: Optional[PathLike] = None,
    trace_or_recording: Optional[PathLike] = None,
    *,
    size: Optional[Tuple[int, int]] = None,
    config: Union[None, PathLike, str, Dict[str, Any]] = None,
    fps: float = 30.0,
    frames: Optional[int] = None,
    from_secs: float = 0.0,
    secs: Optional[float] = None,
    pupil_fit: Union[None, str, Tuple[float, float]] = None,
    pupil_black_cd_m2: Optional[float] = None,
    pupil_white_cd_m2: Optional[float] = None,
) -> None:
    """The checks :func:`render` makes before it opens the scene or reads a
    sample, with the same arguments: the configuration (loaded and checked
    as the CLI loads it), ``size``, ``fps``, ``frames``, ``from_secs``,
    ``secs`` and the pupil light options, against the CLI's bounds (those
    ``GAZELIGHT_PARSE_ONLY=1 gazelight render``/``replay`` checks). Raises
    what ``render`` would raise; returns None when they pass. Nothing is
    rendered: a size of 8192x8192 is checked, not allocated."""
    _render_open(
        **_render_inputs(scene, trace_or_recording, config),
        size=None if size is None else (int(size[0]), int(size[1])),
        fps=fps,
        frames=frames,
        from_secs=from_secs,
        secs=secs,
        pupil_fit=_fit_range(pupil_fit),
        pupil_black_cd_m2=pupil_black_cd_m2,
        pupil_white_cd_m2=pupil_white_cd_m2,
        check_only=True,
    )


def trials(
    replay_dir: PathLike,
    events: str,
    baseline: Tuple[float, float] = (-0.2, 0.0),
    window: Tuple[float, float] = (0.0, 3.0),
    max_invalid: float = 0.5,
    eye: Optional[str] = None,
):
    """The per-trial table of a replay (its ``timeline.csv`` and
    ``events.csv``), as ``gazelight trials`` writes it: one row per event
    whose text matches ``events`` (``*`` any run of characters; without
    ``*``, texts that start with it), the subtractive baseline over
    ``baseline`` s from the onset, peak and mean dilation, the
    light-driven and residual pupil over ``window``, the share without a
    measured pupil and ``valid`` (docs/screen-experiment.md). A pandas
    DataFrame; needs pandas."""
    try:
        import io

        import pandas as pd
    except ImportError as e:  # pragma: no cover - depends on the env
        raise ImportError("gazelight.trials needs pandas (pip install pandas)") from e
    text, _unit = _trials_csv(
        os.fspath(replay_dir),
        events,
        f"{baseline[0]}..{baseline[1]}",
        f"{window[0]}..{window[1]}",
        max_invalid,
        eye,
    )
    return pd.read_csv(io.StringIO(text), dtype={"event": str, "trial": str}, keep_default_na=False, na_values=[""])
