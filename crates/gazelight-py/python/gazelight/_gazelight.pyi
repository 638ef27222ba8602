"""Type stubs of the native module (crates/gazelight-py/src)."""

import os
from typing import Any, Dict, Iterator, List, Optional, Tuple, Union

import numpy as np
import numpy.typing as npt

_Path = Union[str, "os.PathLike[str]"]
_Config = Union[None, str, Dict[str, Any]]

class GazelightError(Exception):
    """An error gazelight reports: the message is the one the CLI prints for the same input."""

class Calibration:
    """A calibration profile mapping a tracker's raw pupil units onto mm."""

    @staticmethod
    def load(path: _Path) -> "Calibration": ...
    @property
    def path(self) -> str: ...
    def to_json(self) -> str: ...

class EyeState:
    """The filtered eye state after a sample (or a live source's newest)."""

    t_secs: float
    gaze_uv: Tuple[float, float]
    gaze_valid: bool
    pupil_mm: Tuple[float, float]
    measured: Tuple[Optional[float], Optional[float]]
    measured_unit: Tuple[Optional[str], Optional[str]]
    pupil_origin: Tuple[str, str]
    confidence: Tuple[float, float]
    blink: bool

class FilterChain:
    """The filter chain `gazelight inspect`, `replay` and the live eye task run."""

    def __init__(self, config: _Config = None, calibration: Union[None, _Path, Calibration] = None) -> None: ...
    def push_pupil(
        self, t_secs: float, eye: int, diameter: float, unit: str = "mm", confidence: float = 1.0
    ) -> EyeState: ...
    def push_gaze(self, t_secs: float, u: float, v: float, confidence: float = 1.0) -> EyeState: ...
    def filter_pupils(
        self,
        t_secs: npt.NDArray[np.float64],
        right: Optional[npt.NDArray[np.float32]] = None,
        left: Optional[npt.NDArray[np.float32]] = None,
        confidence: Optional[npt.NDArray[np.float32]] = None,
        unit: str = "mm",
    ) -> Tuple[Optional[npt.NDArray[np.float32]], Optional[npt.NDArray[np.float32]]]: ...
    @property
    def state(self) -> EyeState: ...
    def stats_json(self) -> str: ...

class PupilLightResponse:
    """W&Y's static target, a latency, first-order constriction and redilation, an observer's range."""

    def __init__(
        self,
        age_years: Optional[float] = None,
        gaze_weight: Optional[float] = None,
        latency_secs: Optional[float] = None,
        constriction_tau_secs: Optional[float] = None,
        redilation_tau_secs: Optional[float] = None,
        scale: float = 1.0,
        offset_mm: float = 0.0,
    ) -> None: ...
    @property
    def params(self) -> Dict[str, float]: ...
    def predict(
        self, t_secs: npt.NDArray[np.float64], luminance_cd_m2: npt.NDArray[np.float64], field_area_deg2: float
    ) -> npt.NDArray[np.float64]: ...
    def static_mm(self, luminance_cd_m2: float, field_area_deg2: float, eyes: int = 2) -> float: ...
    @staticmethod
    def fit(
        t_secs: npt.NDArray[np.float64],
        pupil_mm: npt.NDArray[np.float64],
        luminance_cd_m2: npt.NDArray[np.float64],
        field_area_deg2: float,
        age_years: Optional[float] = None,
        fit_dynamics: bool = True,
        min_samples: int = 20,
    ) -> Tuple["PupilLightResponse", Dict[str, float]]: ...

class Source:
    """A live source as a context manager and an iterator of EyeStates."""

    def __init__(
        self,
        uri: str,
        config: _Config = None,
        calibration: Union[None, _Path, Calibration] = None,
        timeout: Optional[float] = None,
    ) -> None: ...
    def __enter__(self) -> "Source": ...
    def __exit__(self, *args: Any) -> bool: ...
    def close(self) -> None: ...
    def __iter__(self) -> Iterator[EyeState]: ...
    def __next__(self) -> EyeState: ...
    @property
    def uri(self) -> str: ...

class Render:
    """A render in progress (``gazelight.render``): an iterator of
    ``(frame, row)``, one frame rendered per ``next()``."""

    @property
    def frames(self) -> int: ...
    @property
    def size(self) -> Tuple[int, int]: ...
    @property
    def fps(self) -> float: ...
    @property
    def ignored(self) -> List[str]: ...
    @property
    def warnings(self) -> List[str]: ...
    @property
    def pupil_light_params(self) -> List[Dict[str, Any]]: ...
    @property
    def backend(self) -> Optional[str]: ...
    @property
    def backend_reason(self) -> Optional[str]: ...
    def close(self) -> None: ...
    def __iter__(self) -> Iterator[Tuple[Optional[npt.NDArray[Any]], Dict[str, float]]]: ...
    def __next__(self) -> Tuple[Optional[npt.NDArray[Any]], Dict[str, float]]: ...

def render_open(
    scene: Optional[_Path] = None,
    trace: Optional[_Path] = None,
    recording: Optional[_Path] = None,
    *,
    size: Optional[Tuple[int, int]] = None,
    stereo: bool = False,
    config: _Config = None,
    config_name: Optional[str] = None,
    fps: float = 30.0,
    frames: Optional[int] = None,
    retinal: bool = False,
    calibration: Optional[_Path] = None,
    from_secs: float = 0.0,
    secs: Optional[float] = None,
    yaw_deg: Optional[float] = None,
    pitch_deg: Optional[float] = None,
    hfov_deg: Optional[float] = None,
    luminance_scale: Optional[float] = None,
    pupil_fit: Optional[str] = None,
    pupil_black_cd_m2: Optional[float] = None,
    pupil_white_cd_m2: Optional[float] = None,
    check_only: bool = False,
    images: bool = True,
    backend: str = "auto",
    display_light: Optional[_Path] = None,
    display_deg: Optional[str] = None,
    display_cm: Optional[str] = None,
    viewing_distance_cm: Optional[float] = None,
) -> Optional[Render]: ...
def write_png(path: _Path, frame: npt.NDArray[np.uint8]) -> None: ...
def input_kind(path: _Path) -> str: ...
def read_config_text(path: _Path) -> str: ...
def psf(
    pupil_mm: float,
    ppd: Optional[float] = None,
    field_deg: Optional[float] = None,
    age_years: Optional[float] = None,
    pigmentation: Optional[float] = None,
    particles: Optional[int] = None,
    particle_um: Optional[float] = None,
    stray_light: bool = True,
    glare_scale: str = "physical",
) -> Tuple[npt.NDArray[np.float32], Dict[str, Any]]: ...
def read_recording(path: _Path, config: _Config = None, calibration: Any = None) -> Dict[str, Any]: ...
def inspect_json(path: _Path, config: _Config = None, calibration: Any = None) -> str: ...
def trials_csv(
    dir: _Path,
    events: str,
    baseline: str,
    window: str,
    max_invalid: float = 0.5,
    eye: Optional[str] = None,
) -> Tuple[str, str]: ...
