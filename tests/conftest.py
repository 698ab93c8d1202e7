"""Shared fixtures: the stereo scenes in ../shared/data/stereo (skipped when absent)."""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pytest


def data_dir() -> Path:
    """The shared scenes: $STEREODEPTH_DATA, else ../shared/data/stereo beside the repo."""
    env = os.environ.get("STEREODEPTH_DATA")
    if env:
        return Path(env)
    return Path(__file__).resolve().parents[2] / "shared" / "data" / "stereo"


@dataclass
class Scene:
    name: str
    path: Path
    meta: dict[str, Any] = field(repr=False)

    @property
    def left_path(self) -> Path:
        return self.path / "left.png"

    @property
    def right_path(self) -> Path:
        return self.path / "right.png"

    def gt(self) -> np.ndarray:
        return np.load(self.path / "disp_gt.npy")

    def mask(self) -> np.ndarray | None:
        p = self.path / "mask_nonocc.npy"
        return np.load(p) if p.exists() else None


def scenes() -> list[Scene]:
    root = data_dir()
    if not root.is_dir():
        return []
    found = []
    for p in sorted(root.iterdir()):
        if (p / "meta.json").exists() and (p / "disp_gt.npy").exists():
            found.append(Scene(p.name, p, json.loads((p / "meta.json").read_text())))
    return found


@pytest.fixture(scope="session")
def stereo_data_dir() -> Path:
    root = data_dir()
    if not scenes():
        pytest.skip(f"shared stereo scenes not found at {root}")
    return root


@pytest.fixture(scope="session")
def stereo_scenes() -> list[Scene]:
    found = scenes()
    if not found:
        pytest.skip(f"shared stereo scenes not found at {data_dir()}")
    return found
