"""stereodepth over dask arrays: stacks of frames larger than memory (a zarr store, a memory
mapped .npy, a folder of images through ``dask.array``), one frame per chunk.

Each function returns a lazy dask array whose chunks call the native kernels, so the work runs
on whatever scheduler computes it (threads, processes or a dask.distributed cluster) and the
result equals the numpy function's, frame by frame, bit for bit::

    import dask.array as da
    import stereodepth.dask as sdd

    left = da.from_zarr("left.zarr")           # (N, H, W) uint8, any chunking
    right = da.from_zarr("right.zarr")
    disparity = sdd.block_match(left, right, num_disparities=128)
    # or sdd.semi_global_match(left, right, num_disparities=128, paths=8)
    depth = sdd.disparity_to_depth(disparity, focal_px=718.9, baseline_m=0.537)
    depth.to_zarr("depth.zarr")

The matchers keep the numpy API's names and parameters: :func:`block_match` for
:func:`stereodepth.block_match`, :func:`semi_global_match` for
:func:`stereodepth.semi_global_match`.

Needs dask (the ``batch`` extra): ``pip install "stereodepth[batch]"``.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ._validate import native_order

__all__ = ["block_match", "disparity_to_depth", "reproject", "semi_global_match"]


def _da() -> Any:
    try:
        import dask.array as da
    except ImportError as exc:  # pragma: no cover - depends on the environment
        raise ImportError('stereodepth.dask needs dask: pip install "stereodepth[batch]"') from exc
    return da


def _as_dask(name: str, value: Any, *, known_shape: bool = False) -> Any:
    """``value`` checked to be a dask array; with ``known_shape``, one whose shape is known (a
    boolean mask leaves NaN chunk sizes, which the shape checks and the frame-shaped probes
    cannot use)."""
    da = _da()
    if not isinstance(value, da.Array):
        raise TypeError(
            f"{name} must be a dask.array.Array (wrap numpy arrays with dask.array.from_array), "
            f"got {type(value).__name__}"
        )
    if known_shape and any(n != n for n in value.shape):  # NaN: unknown until computed
        raise ValueError(
            f"{name} must have a known shape, got {value.shape} (unknown chunk sizes, as after "
            f"boolean indexing): call {name}.compute_chunk_sizes() first"
        )
    return value


def _stand_in(shape: tuple[Any, ...], dtype: Any) -> np.ndarray:
    """A read-only numpy array of ``shape`` and ``dtype`` (in the machine's byte order) that
    takes no memory: one zero seen through zero strides, for the numpy API's shape and dtype
    checks, whose messages then show the real shape. Unknown (NaN) sizes stand as 1."""
    size = tuple(1 if n != n else int(n) for n in shape)
    return np.broadcast_to(np.zeros((), dtype=np.dtype(dtype).newbyteorder("=")), size)


def _check_disparity(d: Any) -> None:
    """The numpy functions' dtype and shape checks of a disparity map
    (:func:`stereodepth.depth.as_disparity`) on the dask array ``d``, with its shape in the
    messages."""
    from .depth import as_disparity

    stand_in = _stand_in(d.shape, d.dtype)
    try:
        as_disparity(stand_in)
    except ValueError as exc:
        if stand_in.shape == d.shape:
            raise
        # unknown chunk sizes: the message shows them as dask does, not the stand-in's 1
        raise ValueError(str(exc).replace(str(stand_in.shape), str(d.shape))) from None


def _frames_per_chunk(arr: Any, frame_axes: int) -> Any:
    """``arr`` rechunked so that each chunk holds whole frames: the last ``frame_axes`` axes
    in one chunk (the leading axes keep their chunking)."""
    whole = {arr.ndim - k: -1 for k in range(1, frame_axes + 1)}
    if all(len(arr.chunks[ax]) == 1 for ax in whole):
        return arr
    return arr.rechunk(whole)


def disparity_to_depth(disparity: Any, **options: Any) -> Any:
    """:func:`stereodepth.disparity_to_depth` on a dask array of disparity maps, (H, W) or
    (N, H, W) (any chunking: the conversion is per pixel). ``options`` are those of the numpy
    function (``focal_px``, ``baseline_m``, ``doffs_px``, ``scale``, ``dtype``, limits,
    ``invalid_value``, ``min_disparity`` for OpenCV's int16, ``threads``), checked now;
    ``out`` is not accepted."""
    import stereodepth

    d = _as_dask("disparity", disparity)
    if "out" in options:
        raise TypeError("out is not accepted for dask arrays (store the result instead)")
    # Every check of the numpy function, now rather than at compute time: its dtype and shape
    # checks on a stand-in of the real shape (the messages show the user's shape, not a
    # probe's), then the options on an empty map of the same dtype (nothing is computed).
    _check_disparity(d)
    probe = np.zeros((0,) * d.ndim, dtype=d.dtype)
    out_dtype = stereodepth.disparity_to_depth(probe, **options).dtype
    return d.map_blocks(
        _depth_block,
        dtype=out_dtype,
        options=options,
        meta=np.empty((0,) * d.ndim, dtype=out_dtype),
    )


def _depth_block(block: np.ndarray, *, options: dict[str, Any]) -> np.ndarray:
    import stereodepth

    return stereodepth.disparity_to_depth(block, **options)


def block_match(left: Any, right: Any, **params: Any) -> Any:
    """:func:`stereodepth.block_match` on dask arrays of image pairs: (H, W) or (N, H, W) grey,
    or (H, W, 3) / (N, H, W, 3) colour (R, G, B, or B, G, R with ``channel_order="bgr"``, as
    frames read by OpenCV are). A 3-D array whose last axis is 3 or 4 is one colour frame, as
    the numpy function reads it (never a stack of frames 3 or 4 px wide), so (H, W, 4) and
    (H, W, 3) uint16 raise ValueError. Returns the float32 disparity, (H, W) or (N, H, W), NaN
    where invalid. Chunks are first made to hold whole frames (``left`` and ``right`` are
    rechunked alike); ``params`` are those of the numpy function, checked now with the frames'
    shape (an empty frame, the width times ``num_disparities``; ``return_confidence`` is not
    accepted). Each frame is matched as the numpy function matches it, so a uint16 pair is
    stretched over its own range, frame by frame (see :mod:`stereodepth.matching`);
    ``intensity_range=(lo, hi)`` gives every frame of the stack the same scale.
    :func:`semi_global_match` is its semi-global sibling."""
    return _match("bm", "block_match", left, right, params)


def semi_global_match(left: Any, right: Any, **params: Any) -> Any:
    """:func:`stereodepth.semi_global_match` on dask arrays of image pairs, as
    :func:`block_match` does for the block matcher: the same shapes and dtypes ((H, W) or
    (N, H, W) grey uint8/uint16, (H, W, 3) or (N, H, W, 3) uint8 colour), the same float32
    disparity out ((H, W) or (N, H, W), NaN where invalid), whole frames per chunk, each frame
    equal bit for bit to the numpy function's. ``params`` are those of the numpy function
    (``num_disparities``, ``p1``, ``p2``, ``paths``, ``fill``, ``max_memory_mb`` ...), checked
    now, so a bad one raises TypeError or ValueError before anything is computed
    (``return_confidence`` is not accepted), and so do the checks of the frames' shape and
    size: an empty frame, and frames that need more than ``max_memory_mb`` (with
    ``threads=None``, what one thread needs: the cores of the machines that will match are not
    known yet). Each worker thread keeps one matcher for the frames it matches (the
    semi-global matcher's buffers are large: ``max_memory_mb`` is per thread). Source:
    H. Hirschmüller, IEEE PAMI 30(2), 2008."""
    return _match("sgm", "semi_global_match", left, right, params)


def _match(method: str, name: str, left: Any, right: Any, params: dict[str, Any]) -> Any:
    """A matcher of :mod:`stereodepth._methods` over dask arrays: the checks of the numpy
    function ``name`` now, then one task per chunk of whole frames."""
    from stereodepth._methods import options_class

    from .matching import as_image

    la = _as_dask("left", left, known_shape=True)
    ra = _as_dask("right", right, known_shape=True)
    # A big-endian uint16 stack (FITS, PGM) is uint16: matched in the machine's byte order.
    la, ra = (native_order(a) for a in (la, ra))
    if params.get("return_confidence"):
        raise TypeError("return_confidence is not accepted for dask arrays")
    if "isa" in params:
        raise TypeError(f"{name}() got an unexpected keyword argument 'isa'")
    if "num_disparities" not in params:
        raise TypeError(f"{name}() missing required keyword argument: 'num_disparities'")
    checker = options_class(method)
    try:
        options = checker(**params)
    except TypeError as exc:  # the numpy function's name, not the checker's
        raise TypeError(str(exc).replace(f"{checker.__name__}.__init__()", f"{name}()")) from None
    # Each image's dtype first, as the numpy function checks it (matching.as_image, on a 1x1
    # frame of that dtype: its shape passes every shape check and is never shown).
    for image_name, a in (("left", la), ("right", ra)):
        as_image(np.zeros((1, 1), dtype=a.dtype), image_name)
    if la.shape != ra.shape:
        raise ValueError(f"left and right must have the same shape, got {la.shape} and {ra.shape}")
    if la.dtype != ra.dtype:
        raise TypeError(f"left and right must have the same dtype, got {la.dtype} and {ra.dtype}")
    # (N, H, W, 3) and (H, W, 3) uint8 are RGB; (N, H, W) and (H, W) grey. A 3-D array whose
    # last axis is 3 or 4 is one colour frame, as the numpy function reads it: an (H, W, 4)
    # RGBA frame or an (H, W, 3) uint16 one was matched as H grey frames 4 or 3 px wide.
    rgb = la.ndim == 4 or (la.ndim == 3 and la.shape[-1] in (3, 4))
    frame_axes = 3 if rgb else 2
    if la.ndim not in (2, 3, 4) or (rgb and (la.shape[-1] != 3 or la.dtype != np.uint8)):
        raise ValueError(
            "left must have shape (H, W) or (N, H, W) grey, or (H, W, 3) or (N, H, W, 3) uint8 "
            f"RGB, got {la.shape} {la.dtype} (a last axis of 3 or 4 is read as colour "
            "channels, as stereodepth.block_match reads it; drop an alpha channel first)"
        )
    _check_frames(method, la, frame_axes, params, options)
    if la.dtype == np.uint8 and params.get("intensity_range") is not None:
        raise ValueError(
            "intensity_range applies to uint16 images (uint8 images are matched as they are), "
            f"got {params['intensity_range']!r} with uint8 images"
        )
    la = _frames_per_chunk(la, frame_axes)
    ra = ra.rechunk(la.chunks)
    drop = [la.ndim - 1] if rgb else []
    stacked = la.ndim == frame_axes + 1
    meta = np.empty((0,) * (la.ndim - len(drop)), dtype=np.float32)
    return la.map_blocks(
        _match_block,
        ra,
        dtype=np.float32,
        drop_axis=drop,
        method=method,
        params=params,
        stacked=stacked,
        meta=meta,
    )


def _check_frames(
    method: str, left: Any, frame_axes: int, params: dict[str, Any], options: Any
) -> None:
    """The numpy matcher's checks of one frame of ``left``'s shape and dtype (``right``'s are
    the same by now) with ``params`` (checked into ``options``), before anything is computed:
    the pair's own (:func:`stereodepth.matching.check_pair`: an empty frame), then those of
    the native kernel that depend on the frame's size alone, raised by the numpy API's
    matcher itself, with its message, on a frame of zeros that it refuses before any work.

    The kernel's checks are made so that they hold on whatever machine matches: the
    semi-global matcher's memory (:func:`stereodepth.semi_global.memory_estimate` against
    ``max_memory_mb``) is estimated for ``threads`` threads, or for one when ``threads`` is
    None or 0 (every core of the machine that matches, unknown here: a worker whose cores
    need more refuses the frame itself, as before); the block matcher's width times
    ``num_disparities`` is checked with the disparities rounded up to a multiple of 16, the
    rule of :mod:`stereodepth.matching` on every ISA (a worker's ISA cannot change it)."""
    from .matching import (
        DISPARITY_LANES,
        MAX_WIDTH_TIMES_DISPARITIES,
        StereoMatcher,
        check_pair,
    )
    from .semi_global import SemiGlobalMatcher, memory_estimate

    shape = tuple(int(n) for n in left.shape[-frame_axes:])
    # np.zeros of a large frame maps zero pages: nothing is written, read or copied here
    frame = np.zeros(shape, dtype=left.dtype)
    check_pair(frame, frame)
    # The kernels' checks take the frame's size only (not its dtype or channels): they are
    # raised on a grey uint8 frame, whose matcher needs no intensity_range.
    kernel_params = {k: v for k, v in params.items() if k != "intensity_range"}
    rows, cols = shape[:2]
    if method == "sgm":
        need = memory_estimate(
            (rows, cols),
            num_disparities=options.num_disparities,
            paths=options.paths,
            threads=options.threads or 1,
            block_size=options.block_size,
        )
        if need / 1048576.0 > options.max_memory_mb:
            grey = np.zeros((rows, cols), dtype=np.uint8)
            SemiGlobalMatcher(**kernel_params).compute(grey, grey)
    elif cols * (-(-options.num_disparities // DISPARITY_LANES) * DISPARITY_LANES) >= (
        MAX_WIDTH_TIMES_DISPARITIES
    ):  # the width limit of stereodepth.matching, the same on every worker's ISA
        row = np.zeros((1, cols), dtype=np.uint8)
        StereoMatcher(**kernel_params).compute(row, row)


def _match_block(
    left: np.ndarray,
    right: np.ndarray,
    *,
    method: str,
    params: dict[str, Any],
    stacked: bool,
) -> np.ndarray:
    from stereodepth._methods import compute_disparity, thread_matcher

    matcher = thread_matcher(method, **params)
    if not stacked:
        return compute_disparity(matcher, left, right)
    out = np.empty(left.shape[:3], dtype=np.float32)
    for i in range(left.shape[0]):
        out[i] = compute_disparity(matcher, left[i], right[i])
    return out


def reproject(disparity: Any, **options: Any) -> Any:
    """:func:`stereodepth.reproject` on a dask array of disparity maps: (H, W) -> (H, W, 3) or
    (N, H, W) -> (N, H, W, 3) float32, NaN where invalid. Chunks are first made to hold whole
    frames (the pixel coordinates are those of the frame); ``options`` as for the numpy
    function (``Q`` or the rig, ``scale``, limits, ``threads``), checked now."""
    import stereodepth

    d = _as_dask("disparity", disparity, known_shape=True)
    if "out" in options:
        raise TypeError("out is not accepted for dask arrays (store the result instead)")
    _check_disparity(d)
    # The options checked by the numpy function on an empty stack of frames of the real frame
    # shape (for the default cx, cy): every check, and no pixel reprojected while the graph is
    # built (a frame-shaped probe did a whole frame's work, ~1 s at 8000x8000).
    stereodepth.reproject(np.zeros((0, *d.shape[-2:]), dtype=d.dtype), **options)
    d = _frames_per_chunk(d, 2)
    return d.map_blocks(
        _reproject_block,
        dtype=np.float32,
        new_axis=d.ndim,
        chunks=(*d.chunks, (3,)),
        options=options,
        meta=np.empty((0,) * (d.ndim + 1), dtype=np.float32),
    )


def _reproject_block(block: np.ndarray, *, options: dict[str, Any]) -> np.ndarray:
    import stereodepth

    return stereodepth.reproject(block, **options)
