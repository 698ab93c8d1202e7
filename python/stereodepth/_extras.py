"""Optional extras: a check that names what is missing and how to install it, in one line, so
that a command can refuse before it does any work."""

from __future__ import annotations

import importlib

__all__ = ["require"]

#: The module of each optional dependency, with its pip name and the extra that installs it.
_EXTRAS = {
    "PIL": ("Pillow", "batch"),
    "tqdm": ("tqdm", "batch"),
    "distributed": ("dask[distributed]", "batch"),
    "dask": ("dask", "batch"),
    "matplotlib": ("matplotlib", "plot"),
}


def require(module: str, purpose: str) -> None:
    """Raises ImportError, ``<purpose> needs <package>, which is not installed: pip install
    "stereodepth[<extra>]"``, unless ``module`` imports."""
    try:
        importlib.import_module(module)
    except ImportError:
        package, extra = _EXTRAS.get(module.partition(".")[0], (module, ""))
        hint = f'pip install "stereodepth[{extra}]"' if extra else f"pip install {package}"
        raise ImportError(f"{purpose} needs {package}, which is not installed: {hint}") from None
