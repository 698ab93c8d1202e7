"""stereodepth: stereo camera geometry and image pairs to depth, fast.

- :class:`StereoRig`: the depth calculator (depth, resolution, field of view, tables).
- :func:`disparity_to_depth`: native, threaded disparity-map to depth-map conversion.
- :func:`block_match`, :class:`StereoMatcher`: native block-matching disparity (census or SAD,
  sub-pixel, validity checks); :func:`to_opencv_disparity` for OpenCV's int16 x16 format.
- :func:`reproject`, :func:`write_ply`: disparity maps to XYZ point clouds and PLY files.
- :mod:`stereodepth.reference`: the pure-numpy oracle of every native kernel.
"""

from __future__ import annotations

from typing import Any

from . import _core
from .depth import disparity_to_depth
from .matching import StereoMatcher, block_match, to_opencv_disparity
from .pointcloud import reproject, write_ply
from .rig import DepthTable, StereoRig
from .semi_global import SemiGlobalMatcher, semi_global_match

__version__: str = _core.__version__

__all__ = [
    "DepthTable",
    "SemiGlobalMatcher",
    "StereoMatcher",
    "StereoRig",
    "__version__",
    "block_match",
    "build_info",
    "disparity_to_depth",
    "reproject",
    "semi_global_match",
    "to_opencv_disparity",
    "write_ply",
]


def build_info() -> dict[str, Any]:
    """How the native core was built and what it runs on this machine.

    Keys: ``version``, ``compiler``, ``isa`` (the instruction set chosen at run time:
    ``baseline``, ``avx2`` or ``avx512``; the environment variable STEREODEPTH_ISA caps it),
    ``supported_isas``, ``default_threads`` (the cores this process may use), ``eigen``,
    ``pybind11`` and ``sanitizers``.
    """
    return dict(_core.build_info())
