"""Public submodules are attributes of the package, imported on first use (PEP 562)."""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

import stereodepth

SUBMODULES = [
    "batch",
    "calib",
    "charts",
    "cli",
    "colormap",
    "dask",
    "depth",
    "evaluation",
    "io",
    "matching",
    "metrics",
    "plotting",
    "pointcloud",
    "rectify",
    "reference",
    "rig",
    "sample",
    "semi_global",
    "web",
]
#: Submodules that need no optional extra: using them must not import one.
CORE = [
    "calib",
    "charts",
    "colormap",
    "depth",
    "io",
    "matching",
    "metrics",
    "pointcloud",
    "rectify",
    "reference",
    "rig",
    "sample",
    "semi_global",
]
#: Optional extras that ``import stereodepth`` must not import.
HEAVY = ["dask", "distributed", "matplotlib", "fastapi", "uvicorn", "plotly", "PIL", "cv2", "tqdm"]


def _package_path() -> str:
    return str(Path(stereodepth.__file__).resolve().parents[1])


def test_import_is_light_and_every_submodule_is_an_attribute() -> None:
    script = textwrap.dedent(
        f"""
        import json, sys
        import stereodepth as sd
        heavy = {HEAVY!r}
        before = sorted(m for m in heavy if m in sys.modules)
        listed = sorted(set({SUBMODULES!r}) - set(dir(sd)))
        for name in {CORE!r}:
            getattr(sd, name)
        core = sorted(m for m in heavy if m in sys.modules)
        got = {{}}
        for name in {SUBMODULES!r}:
            module = getattr(sd, name)
            got[name] = module.__name__
        print(json.dumps({{"before": before, "core": core, "unlisted": listed, "got": got}}))
        """
    )
    env = dict(os.environ, PYTHONPATH=_package_path())
    done = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, env=env, check=False
    )
    assert done.returncode == 0, done.stderr
    report = json.loads(done.stdout)
    assert report["before"] == [], "import stereodepth loaded optional extras"
    assert report["core"] == [], "a submodule without extras imported one"
    assert report["unlisted"] == []
    assert report["got"] == {name: f"stereodepth.{name}" for name in SUBMODULES}


def test_reference_block_match_through_the_attribute() -> None:
    import numpy as np

    import stereodepth as sd

    left = np.random.default_rng(0).integers(0, 256, (12, 40), dtype=np.uint8)
    right = np.roll(left, -3, axis=1)
    got = sd.reference.block_match(left, right, num_disparities=8, block_size=5)
    assert got.shape == left.shape and got.dtype == np.float32


def test_unknown_attribute_is_an_attribute_error() -> None:
    with pytest.raises(AttributeError, match="module 'stereodepth' has no attribute 'nope'"):
        _ = stereodepth.nope  # type: ignore[attr-defined]
    assert not hasattr(stereodepth, "_private_thing")


def test_package_docstring_names_every_submodule() -> None:
    # help(stereodepth) is where a reader looks for what the package holds: sample (the
    # synthetic pair), semi_global, rectify and colormap were missing from its list.
    doc = stereodepth.__doc__ or ""
    missing = [
        name
        for name in SUBMODULES
        if f"``{name}``" not in doc and f"``stereodepth.{name}``" not in doc
    ]
    assert missing == []
