from typing import Any

import numpy as np

__version__: str

def build_info() -> dict[str, Any]: ...
def _cgroup_cpu_limit(root: str) -> int: ...
def _rgb_to_grey(rgb: np.ndarray, isa: str = "auto", channel_order: str = "rgb") -> np.ndarray: ...
def _stretch_uint16_pair(
    left: np.ndarray,
    right: np.ndarray,
    intensity_range: tuple[int, int] | None = None,
    threads: int = 0,
    isa: str = "auto",
) -> tuple[np.ndarray, np.ndarray]: ...
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
        clip_border: bool = True,
    ) -> None: ...
    def compute(
        self,
        left: np.ndarray,
        right: np.ndarray,
        disparity: np.ndarray,
        confidence: np.ndarray | None = None,
        channel_order: str = "rgb",
    ) -> None: ...
    @property
    def threads(self) -> int: ...
    @property
    def isa(self) -> str: ...

def stereo_rectify(
    K1: np.ndarray,
    D1: np.ndarray,
    K2: np.ndarray,
    D2: np.ndarray,
    model: str,
    width: int,
    height: int,
    R: np.ndarray,
    T: np.ndarray,
    alpha: float,
    new_width: int,
    new_height: int,
    zero_disparity: bool,
) -> dict[str, Any]: ...
def fisheye_stereo_rectify(
    K1: np.ndarray,
    D1: np.ndarray,
    K2: np.ndarray,
    D2: np.ndarray,
    width: int,
    height: int,
    R: np.ndarray,
    T: np.ndarray,
    balance: float,
    fov_scale: float,
    new_width: int,
    new_height: int,
    zero_disparity: bool,
) -> dict[str, Any]: ...
def undistort_points(
    K: np.ndarray, D: np.ndarray, model: str, points: np.ndarray
) -> np.ndarray: ...
def init_undistort_rectify_map(
    K: np.ndarray,
    D: np.ndarray,
    model: str,
    R: np.ndarray,
    P: np.ndarray,
    map_x: np.ndarray,
    map_y: np.ndarray,
    threads: int,
) -> None: ...

class RemapTable:
    def __init__(
        self,
        map_x: np.ndarray,
        map_y: np.ndarray,
        src_rows: int,
        src_cols: int,
        precision: str,
        threads: int,
    ) -> None: ...
    def apply(
        self, image: np.ndarray, out: np.ndarray, threads: int, isa: str = "auto"
    ) -> None: ...
    @property
    def shape(self) -> tuple[int, int]: ...
    @property
    def source_shape(self) -> tuple[int, int]: ...
    @property
    def precision(self) -> str: ...

class SemiGlobalMatcher:
    def __init__(
        self,
        num_disparities: int,
        min_disparity: int,
        block_size: int,
        p1: int,
        p2: int,
        p2_step: int,
        paths: int,
        subpixel: str,
        uniqueness_ratio: float,
        lr_max_diff: float,
        median: bool,
        speckle_window: int,
        speckle_range: float,
        clip_border: bool,
        max_memory_mb: float,
        threads: int,
        isa: str = "auto",
    ) -> None: ...
    def compute(
        self,
        left: np.ndarray,
        right: np.ndarray,
        disparity: np.ndarray,
        confidence: np.ndarray | None = None,
        channel_order: str = "rgb",
    ) -> None: ...
    def check_size(self, rows: int, cols: int) -> None: ...
    @property
    def threads(self) -> int: ...
    @property
    def isa(self) -> str: ...

def semi_global_memory(
    rows: int,
    cols: int,
    num_disparities: int,
    paths: int,
    threads: int,
    isa: str = "auto",
    block_size: int = 3,
) -> int: ...
