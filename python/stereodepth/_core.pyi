from typing import Any

import numpy as np

__version__: str

def build_info() -> dict[str, Any]: ...
def disparity_to_depth(
    disparity: np.ndarray,
    out: np.ndarray,
    focal_px: float,
    baseline_m: float,
    doffs_px: float,
    scale: float,
    min_depth_m: float,
    max_depth_m: float,
    invalid_value: float | None,
    negative_invalid: bool,
    threads: int,
    isa: str = "auto",
) -> None: ...
