"""stereodepth: stereo camera geometry and image pairs to depth, fast.

- :class:`StereoRig`: the depth calculator (depth, resolution, field of view, tables).
- :func:`disparity_to_depth`: native, threaded disparity-map to depth-map conversion.
- :func:`block_match`, :class:`StereoMatcher`: native block-matching disparity (census or SAD,
  sub-pixel, validity checks); :func:`to_opencv_disparity` for OpenCV's int16 x16 format.
- :func:`from_opencv_disparity`: OpenCV's int16 x16 output back to float pixels with NaN holes.
- :func:`reproject`, :func:`write_ply`: disparity maps to XYZ point clouds and PLY files.
- :class:`StereoRectifier`, :func:`stereo_rectify`, :func:`init_undistort_rectify_map`,
  :func:`remap`: raw, distorted pairs to rectified pairs, natively.
- :mod:`stereodepth.reference`: the pure-numpy oracle of every native kernel.

Every public submodule is an attribute of the package, imported on first use (PEP 562), so
``import stereodepth`` stays light and optional extras load only when their module is used:
``stereodepth.reference``, ``io``, ``metrics``, ``dask`` (the ``batch`` extra), ``calib``,
``matching``, ``semi_global``, ``rig``, ``depth``, ``pointcloud``, ``rectify``, ``colormap``,
``sample`` (a synthetic pair with its true disparity: ``sample.sample_pair()``),
``evaluation``, ``batch``, ``plotting`` (``plot``), ``charts``, ``web`` (``web``) and ``cli``.
"""

from __future__ import annotations

import importlib
from typing import Any

from . import _core
from .colormap import colorize, save_colorized
from .depth import disparity_to_depth, from_opencv_disparity
from .matching import StereoMatcher, block_match, to_opencv_disparity
from .pointcloud import reproject, write_ply
from .rectify import StereoRectifier, init_undistort_rectify_map, remap, stereo_rectify
from .rig import DepthTable, StereoRig
from .semi_global import SemiGlobalMatcher, semi_global_match

__version__: str = _core.__version__

__all__ = [
    "DepthTable",
    "SemiGlobalMatcher",
    "StereoMatcher",
    "StereoRectifier",
    "StereoRig",
    "__version__",
    "block_match",
    "build_info",
    "colorize",
    "disparity_to_depth",
    "from_opencv_disparity",
    "init_undistort_rectify_map",
    "remap",
    "reproject",
    "save_colorized",
    "semi_global_match",
    "stereo_rectify",
    "to_opencv_disparity",
    "write_ply",
]


def build_info() -> dict[str, Any]:
    """How the native core was built and what it runs on this machine.

    Keys: ``version``, ``compiler``, ``isa`` (the instruction set chosen at run time:
    ``baseline``, ``avx2`` or ``avx512``, the last on processors with AVX-512 F, BW, VL, DQ,
    VPOPCNTDQ and BITALG; the environment variable STEREODEPTH_ISA caps it,
    and any value of it other than ``auto``, ``baseline``, ``avx2`` or ``avx512`` makes this
    and every kernel called with ``isa="auto"`` raise ValueError; a kernel given a named
    ``isa`` runs that one),
    ``supported_isas``, ``default_threads`` (the cores this process may use), ``eigen``,
    ``pybind11`` and ``sanitizers``.
    """
    return dict(_core.build_info())


#: The public submodules, reachable as attributes and imported on first access.
_SUBMODULES: frozenset[str] = frozenset(
    {
        "batch",
        "calib",
        "charts",
        "colormap",
        "cli",
        "dask",
        "depth",
        "evaluation",
        "io",
        "matching",
        "metrics",
        "plotting",
        "pointcloud",
        "reference",
        "rectify",
        "rig",
        "sample",
        "semi_global",
        "web",
    }
)


def __getattr__(name: str) -> Any:
    """Imports a public submodule on first access (PEP 562): ``stereodepth.reference``."""
    if name in _SUBMODULES:
        # import_module also binds the module as an attribute: this runs once per name.
        return importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | _SUBMODULES)
