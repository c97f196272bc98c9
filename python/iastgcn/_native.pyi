"""Type hints of the native module (src/embed/python/)."""

from os import PathLike
from typing import Any, Callable, Optional, Sequence, Tuple, Union

import numpy as np
import numpy.typing as npt

_Path = Union[str, PathLike]
_Progress = Optional[Callable[[str, str, int, int], Any]]

__version__: str

class Error(Exception):
    """Every failure of the engine, with its message (naming the file, field or tensor)."""

class Predictor:
    """A checkpoint loaded for a control loop or for batches of windows; or an ensemble
    file (.toml, as `iastgcn confidence` writes them): its members' mean prediction and
    a calibrated interval, from sensor values (dt) only."""

    def __init__(
        self,
        checkpoint: _Path,
        *,
        dt: Optional[float] = None,
        backend: str = "native",
        threads: int = 1,
    ) -> None: ...
    @property
    def nodes(self) -> list[str]: ...
    @property
    def window_shape(self) -> Tuple[int, int, int]: ...
    @property
    def look_ahead(self) -> int: ...
    @property
    def variant(self) -> str: ...
    @property
    def backend(self) -> str: ...
    @property
    def dt(self) -> Optional[float]: ...
    @property
    def threads(self) -> int: ...
    @threads.setter
    def threads(self, threads: int) -> None: ...
    @property
    def members(self) -> int: ...
    @property
    def interval_level(self) -> Optional[float]: ...
    def interval(self) -> Optional[Tuple[float, float]]: ...
    def push(self, frame: npt.ArrayLike) -> bool: ...
    def push_features(self, step: npt.ArrayLike) -> bool: ...
    def predict_latest(self) -> Optional[npt.NDArray[np.float64]]: ...
    def predict(self, window: npt.ArrayLike) -> npt.NDArray[np.float64]: ...
    def predict_batch(
        self, windows: npt.ArrayLike, standardised: bool = False
    ) -> npt.NDArray[np.float64]: ...
    def reset(self) -> None: ...

def record_data(
    out: _Path,
    minutes: float = 2.0,
    machine_seed: int = 1,
    recipe: str = "use-like",
    sessions: Optional[int] = None,
    placement: Optional[str] = None,
    path_order: Optional[str] = None,
    closed_loop: Optional[bool] = None,
    config: Optional[_Path] = None,
    progress: _Progress = None,
) -> dict[str, Any]: ...
def calibrate(
    measurements: _Path,
    out: Optional[_Path] = None,
    hold_out_every: int = 5,
    test: Optional[_Path] = None,
    recordings: Sequence[_Path] = (),
) -> dict[str, Any]: ...
def calibrate_arm(
    description: _Path,
    poses: _Path,
    out: Optional[_Path] = None,
    hold_out_every: int = 5,
    test: Optional[_Path] = None,
) -> dict[str, Any]: ...
def train(
    recordings: Sequence[_Path],
    calibration: _Path,
    out: _Path,
    config: Optional[_Path] = None,
    variant: Optional[str] = None,
    max_epochs: Optional[int] = None,
    patience: Optional[int] = None,
    graph: Optional[_Path] = None,
    robot: Optional[_Path] = None,
    resume: Optional[_Path] = None,
    progress: _Progress = None,
) -> dict[str, Any]: ...
def refine(
    recordings: Sequence[_Path],
    calibration: _Path,
    model: _Path,
    out: _Path,
    config: Optional[_Path] = None,
    graph: Optional[_Path] = None,
    robot: Optional[_Path] = None,
    progress: _Progress = None,
) -> dict[str, Any]: ...
def adapt(
    recordings: Sequence[_Path],
    calibration: _Path,
    model: _Path,
    out: _Path,
    method: str = "offset",
    config: Optional[_Path] = None,
    graph: Optional[_Path] = None,
    robot: Optional[_Path] = None,
    progress: _Progress = None,
) -> dict[str, Any]: ...
def evaluate(
    models: Sequence[_Path],
    recordings: Sequence[_Path],
    calibration: _Path,
    out: _Path,
    config: Optional[_Path] = None,
    held_out_minutes: Optional[float] = None,
    held_out_seed: Optional[int] = None,
    graph: Optional[_Path] = None,
    progress: _Progress = None,
    held_out_sessions: Optional[int] = None,
) -> dict[str, Any]: ...
