"""The matchers by name, for the commands and the Dask functions that let the user choose one:
``"bm"`` (block matching, :class:`stereodepth.StereoMatcher`) and ``"sgm"`` (semi-global
matching, :class:`stereodepth.SemiGlobalMatcher`).

One table says which class, which checked options (:class:`~stereodepth.matching.
BlockMatchOptions`, :class:`~stereodepth.semi_global.SemiGlobalOptions`) and which keyword
options each method has, so that ``stereodepth batch --method`` and :mod:`stereodepth.dask`
check a user's options by the same rules as the matchers themselves; and
:func:`thread_matcher` keeps one matcher per thread for jobs that match pair after pair.
"""

from __future__ import annotations

import inspect
import threading
from typing import Any

import numpy as np

__all__ = [
    "METHODS",
    "check_method",
    "matcher_class",
    "matcher_keywords",
    "options_class",
    "release_thread_matcher",
    "thread_matcher",
]

#: The matchers: block matching (the default everywhere) and semi-global matching.
METHODS = ("bm", "sgm")
#: What each method is called in messages and help texts.
METHOD_NAMES = {"bm": "block matching", "sgm": "semi-global matching"}


def check_method(method: Any, name: str = "method") -> str:
    """``method`` when it is one of :data:`METHODS`; TypeError or ValueError naming ``name``
    and the value otherwise."""
    if not isinstance(method, str):
        raise TypeError(
            f"{name} must be one of {', '.join(map(repr, METHODS))}, got "
            f"{type(method).__name__} {method!r}"
        )
    if method not in METHODS:
        raise ValueError(f"{name} must be one of {', '.join(map(repr, METHODS))}, got {method!r}")
    return method


def matcher_class(method: str) -> type[Any]:
    """:class:`stereodepth.StereoMatcher` for ``"bm"``, :class:`stereodepth.SemiGlobalMatcher`
    for ``"sgm"``."""
    if check_method(method) == "bm":
        from .matching import StereoMatcher

        return StereoMatcher
    from .semi_global import SemiGlobalMatcher

    return SemiGlobalMatcher


def options_class(method: str) -> type[Any]:
    """The class that checks a method's parameters (the matcher's own checks, without making
    a matcher): ``BlockMatchOptions`` or ``SemiGlobalOptions``."""
    if check_method(method) == "bm":
        from .matching import BlockMatchOptions

        return BlockMatchOptions
    from .semi_global import SemiGlobalOptions

    return SemiGlobalOptions


def block_sizes_text() -> tuple[str, str]:
    """The block sizes each method takes, for the command lines' help: the block matcher's
    ranges by cost ("3 to 63 with --cost census, 3 to 31 with --cost sad"; odd sizes) and the
    semi-global matcher's sizes ("1 or 3"), from the matchers' own constants."""
    from .matching import MAX_BLOCK_SIZE
    from .semi_global import BLOCK_SIZES

    costs = ", ".join(f"3 to {top} with --cost {cost}" for cost, top in MAX_BLOCK_SIZE.items())
    return costs, " or ".join(map(str, BLOCK_SIZES))


def matcher_keywords(method: str) -> list[str]:
    """The keyword options of a method's matcher class, in its signature's order (``isa``,
    for testing and benchmarking, left out)."""
    params = inspect.signature(matcher_class(method).__init__).parameters
    return [n for n, p in params.items() if p.kind is inspect.Parameter.KEYWORD_ONLY and n != "isa"]


_thread_state = threading.local()


def thread_matcher(method: str, **params: Any) -> Any:
    """This thread's matcher of ``method`` with ``params``: made on the first call and reused
    while the method and parameters stay the same, so that a job matching pair after pair (the
    batch command, the Dask functions) does not allocate and fault in the matcher's buffers
    again for every pair. Each thread keeps one matcher, released with the thread or when the
    method or parameters change. Raises the matcher's TypeError or ValueError for bad
    ``params``."""
    # The values' types are part of the key: 1 == True == 1.0, but a matcher made with one
    # must not answer for another that its checks would refuse. They come before the values,
    # so that a comparison stops at a type that differs before it compares (say) a cached
    # tuple with an array. The key is built on every one-shot call, so it is kept cheap.
    # The items of a tuple or list (intensity_range) are typed too: after (1, 4095), an
    # intensity_range of (True, 4095) or (1.0, 4095) compared equal and skipped the checks.
    # Lists are copied into the key: one kept by reference would follow the caller's later
    # edits in place and keep answering for the old matcher.
    # A call with the parameters of the last one, in the same order, none of them a tuple or
    # list (the one-shot functions' case), is found from their types and values as given,
    # without sorting or snapshots (which took about 1.5 % of a one-shot call on Tsukuba,
    # 384 x 288). The types are compared first, so the values compared are of one type.
    cached = getattr(_thread_state, "matcher", None)
    types = tuple(map(type, params.values()))
    quick = (method, types, tuple(params.items()))
    if cached is not None and cached[2] == quick:
        return cached[1]
    names = tuple(sorted(params))
    values = tuple([_snapshot(params[k]) for k in names])
    key = (method, names, tuple(map(_types, values)), values)
    if cached is None or cached[0] != key:
        check_method(method)
        _thread_state.matcher = None  # release the old buffers before making the new ones
        plain = not any(issubclass(t, (tuple, list)) for t in types)
        cached = (key, matcher_class(method)(**params), quick if plain else None)
        _thread_state.matcher = cached
    return cached[1]


def _snapshot(value: Any) -> Any:
    """``value``, a list as a tuple of its items (its type stays in the key's types)."""
    return tuple(value) if isinstance(value, list) else value


def _types(value: Any) -> Any:
    """The type of ``value``, with those of its items for a tuple or list (one level: the
    parameters hold no deeper containers)."""
    if isinstance(value, (tuple, list)):
        return (type(value), tuple(map(type, value)))
    return type(value)


def release_thread_matcher() -> None:
    """Drops this thread's matcher (:func:`thread_matcher`) and with it its buffers."""
    _thread_state.matcher = None


def compute_disparity(matcher: Any, left: np.ndarray, right: np.ndarray) -> np.ndarray:
    """``matcher.compute(left, right)``, the disparity alone (the matchers made here never
    return a confidence)."""
    disparity = matcher.compute(left, right)
    if not isinstance(disparity, np.ndarray):
        raise TypeError("the matcher returned more than the disparity (return_confidence=True)")
    return disparity
