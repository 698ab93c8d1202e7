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
    invalid_below: float | None,
    threads: int,
    isa: str = "auto",
) -> None: ...
def reproject(
    disparity: np.ndarray,
    out: np.ndarray,
    q: np.ndarray,
    scale: float,
    min_depth: float,
    max_depth: float,
    invalid_value: float | None,
    invalid_below: float | None,
    threads: int,
    isa: str = "auto",
) -> None: ...

class BlockMatcher:
    def __init__(
        self,
        num_disparities: int,
        min_disparity: int,
        block_size: int,
        cost: str,
        subpixel: str,
        uniqueness_ratio: float,
        texture_threshold: float,
        lr_max_diff: float,
        speckle_window: int,
        speckle_range: float,
        threads: int,
        isa: str = "auto",
    ) -> None: ...
    def compute(
        self,
        left: np.ndarray,
        right: np.ndarray,
        disparity: np.ndarray,
        confidence: np.ndarray | None = None,
    ) -> None: ...
    @property
    def threads(self) -> int: ...
    @property
    def isa(self) -> str: ...
