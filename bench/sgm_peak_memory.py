"""Peak memory of one semi-global matching call above its inputs and outputs.

Each configuration runs in a fresh process: the pair (random dots, the right image the left
shifted by 40 px) is made without large temporaries, the high-water mark of the resident set
(VmHWM, Linux) is reset to the current resident size through /proc/self/clear_refs, one
``semi_global_match`` call runs, and the growth of VmHWM minus the outputs it returns (the
float32 disparity and confidence, 8 bytes per pixel) is printed: the matcher's own buffers.

    PYTHONPATH=python python bench/sgm_peak_memory.py [--shape 1080 1920] [--ndisp 256]
        [--threads 1 2] [--speckle 100] [--scene]

``--scene``: the Adirondack pair resized to the shape (``hd_pair`` of
bench_semi_global.py, made once and saved as .npy, which each process loads) instead of the
random dots; real disparities give the speckle filter its regions to label.

Linux only (VmHWM and clear_refs); the estimate behind ``max_memory_mb``
(:func:`stereodepth.semi_global.memory_estimate`) is printed beside each figure.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path
from typing import Any

MIB = 1 << 20


def status_kib(field: str) -> int:
    with open("/proc/self/status", encoding="ascii") as f:
        for line in f:
            if line.startswith(field + ":"):
                return int(line.split()[1])
    raise RuntimeError(f"{field} not in /proc/self/status")


def measure(
    h: int, w: int, ndisp: int, threads: int, rgb: bool, paths: int, speckle: int, scene: str
) -> Any:
    """In this process: the growth of the peak resident set over one call, in bytes."""
    import numpy as np

    import stereodepth as sd
    from stereodepth.semi_global import memory_estimate

    if scene:
        left, right = (np.load(Path(scene) / f"{side}.npy") for side in ("left", "right"))
        if rgb:
            left, right = (np.ascontiguousarray(np.stack([a] * 3, axis=2)) for a in (left, right))
    else:
        rng = np.random.default_rng(1)
        shape = (h, w + 40, 3) if rgb else (h, w + 40)
        wide = rng.integers(0, 256, size=shape, dtype=np.uint8)
        left = np.ascontiguousarray(wide[:, :-40])  # left[x] = right[x - 40]
        right = np.ascontiguousarray(wide[:, 40:])
        del wide
    kw: dict[str, Any] = {
        "num_disparities": ndisp,
        "threads": threads,
        "paths": paths,
        "speckle_window": speckle,
        "return_confidence": True,
    }
    sd.semi_global_match(left[:8, :64], right[:8, :64], **{**kw, "num_disparities": 16})
    with open("/proc/self/clear_refs", "w", encoding="ascii") as f:
        f.write("5")  # VmHWM := VmRSS
    before = status_kib("VmRSS")
    disp, conf = sd.semi_global_match(left, right, **kw)
    peak = status_kib("VmHWM")
    outputs = disp.nbytes + conf.nbytes
    valid = float(np.isfinite(disp).mean())
    return {
        "growth": (peak - before) * 1024 - outputs,
        "estimate": memory_estimate((h, w), num_disparities=ndisp, paths=paths, threads=threads),
        "isa": str(sd.build_info()["isa"]),
        "valid": valid,
    }


def run(
    h: int, w: int, ndisp: int, threads: int, rgb: bool, paths: int, speckle: int, scene: str
) -> Any:
    """measure() in a fresh interpreter (this file run with --child)."""
    args = [sys.executable, __file__, "--child", "--shape", str(h), str(w), "--ndisp", str(ndisp)]
    args += ["--threads", str(threads), "--paths", str(paths), "--speckle", str(speckle)]
    args += ["--rgb"] if rgb else []
    args += ["--scene-dir", scene] if scene else []
    out = subprocess.run(args, check=True, capture_output=True, text=True, env=os.environ)
    return json.loads(out.stdout)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--shape", type=int, nargs=2, default=[1080, 1920])
    ap.add_argument("--ndisp", type=int, default=256)
    ap.add_argument("--threads", type=int, nargs="*", default=[1, 2])
    ap.add_argument("--paths", type=int, default=3)
    ap.add_argument("--speckle", type=int, default=100)
    ap.add_argument("--scene", action="store_true")
    ap.add_argument("--rgb", action="store_true")
    ap.add_argument("--child", action="store_true")
    ap.add_argument("--scene-dir", default="")
    a = ap.parse_args()
    h, w = a.shape
    if a.child:
        r = measure(h, w, a.ndisp, a.threads[0], a.rgb, a.paths, a.speckle, a.scene_dir)
        print(json.dumps(r))
        return
    with tempfile.TemporaryDirectory() as tmp:
        if a.scene:
            import numpy as np

            sys.path.insert(0, str(Path(__file__).resolve().parent))
            from bench_semi_global import hd_pair

            for side, image in zip(("left", "right"), hd_pair(w, h), strict=True):
                np.save(Path(tmp) / f"{side}.npy", image)
        report(a, h, w, tmp if a.scene else "")


def report(a: Any, h: int, w: int, scene: str) -> None:
    pair = "Adirondack resized" if scene else "random dots"
    print(f"{h}x{w} {pair}, ndisp {a.ndisp}, paths={a.paths}, speckle_window={a.speckle}")
    for rgb in (False, True):
        for t in a.threads:
            r = run(h, w, a.ndisp, t, rgb, a.paths, a.speckle, scene)
            print(
                f"  {'rgb ' if rgb else 'grey'} threads={t} isa={r['isa']}: peak above inputs and "
                f"outputs {r['growth'] / MIB:7.2f} MiB (estimate {r['estimate'] / MIB:7.2f} MiB; "
                f"valid {r['valid']:.2f})"
            )


if __name__ == "__main__":
    main()
