"""Type stub of the compiled fleet_send.pyx."""

from collections.abc import Callable
from typing import Any

import numpy as np
import numpy.typing as npt

def monotonic_s() -> float: ...
def send_window(
    order: npt.NDArray[np.int64],
    due_s: npt.NDArray[np.float64],
    datas: list[bytes],
    owners: npt.NDArray[np.int64],
    fd_start: npt.NDArray[np.int32],
    fds: npt.NDArray[np.int32],
    sent: npt.NDArray[np.int64],
    emits: list[Any] | None,
    failed: Callable[[int, OSError], object],
    flush: Callable[[], object],
    stop_wait: Callable[[float], bool],
    wall0: float,
    min_sleep_s: float,
) -> tuple[int, float]: ...
