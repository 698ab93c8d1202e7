"""The calibration types: :class:`StereoCalibration` (a calibrated pair, raw or rectified, in
OpenCV's conventions) and :class:`Calibration` (the rectified rig a batch job computes with)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from ._common import (
    _check_array,
    _check_distortion,
    _check_image_size,
    _check_intrinsics,
    _check_model,
    _check_rotation,
    _differ,
    _fail,
)

if TYPE_CHECKING:
    from ..rig import StereoRig

__all__ = ["Calibration", "StereoCalibration"]


@dataclass(frozen=True, eq=False)
class StereoCalibration:
    """A calibrated stereo pair, in OpenCV's conventions, from any calibration file.

    A point X in the left camera's frame is ``R @ X + T`` in the right camera's frame (what
    ``cv2.stereoCalibrate`` returns). Every array is float64; the readers check the shapes,
    that every value is finite, that the rotations are rotations (``R R^T = I`` and
    ``det R = +1`` within 1e-5, what a rotation printed to 6 significant digits keeps; such
    a rounded one is replaced by the nearest rotation) and that the distortion coefficients
    fit the model, and
    raise ValueError naming the file and the key otherwise; building one directly runs the
    same checks and names the field.

    Fields:
        K1, K2: (3, 3) intrinsics of the left and right camera, pixels.
        D1, D2: (n,) distortion coefficients: none for ``"none"``; k1 k2 p1 p2 [k3 [k4 k5
            k6]] (4, 5 or 8) for ``"plumb_bob"`` (Brown-Conrady, ROS's plumb_bob and
            rational_polynomial, Kalibr's radtan, OpenCV's default model; OpenCV's 12 and
            14 coefficient forms, as cv2.stereoCalibrate returns them with
            CALIB_RATIONAL_MODEL, are kept as their first 8 when the rest are 0); k1 k2 k3 k4
            for ``"equidistant"`` (Kannala-Brandt, OpenCV's fisheye module, Kalibr's
            equidistant).
        distortion_model: ``"none"``, ``"plumb_bob"`` or ``"equidistant"``, both cameras.
        R: (3, 3) rotation from the left camera to the right.
        T: (3,) translation from the left camera to the right, metres (for a right camera
            at baseline B to the right of the left one, about (-B, 0, 0)).
        image_size: (width, height) of the images in pixels.
        R1, R2, P1, P2, Q: the rectification (3, 3), projections (3, 4) and disparity-to-
            depth matrix (4, 4) of ``cv2.stereoRectify``, where the source holds them (P's
            last column and Q in metres, as T), else None.
        rectified: True for already rectified sources (Middlebury, KITTI): R is the identity,
            the distortion ``"none"``, and R1, R2, P1, P2, Q are filled in.
        source: the file or files it was read from.
    """

    K1: np.ndarray
    D1: np.ndarray
    K2: np.ndarray
    D2: np.ndarray
    distortion_model: str
    R: np.ndarray
    T: np.ndarray
    image_size: tuple[int, int]
    R1: np.ndarray | None = None
    R2: np.ndarray | None = None
    P1: np.ndarray | None = None
    P2: np.ndarray | None = None
    Q: np.ndarray | None = None
    rectified: bool = False
    source: str = ""

    def __post_init__(self) -> None:
        where = self.source or "StereoCalibration"
        model = _check_model(self.distortion_model, where, "distortion_model")
        fields: dict[str, Any] = {
            "distortion_model": model,
            "K1": _check_intrinsics(self.K1, where, "K1"),
            "K2": _check_intrinsics(self.K2, where, "K2"),
            "D1": _check_distortion(self.D1, model, where, "D1"),
            "D2": _check_distortion(self.D2, model, where, "D2"),
            "R": _check_rotation(self.R, where, "R"),
            "T": _check_array(self.T, where, "T", (3,)),
            "image_size": _check_image_size(self.image_size, where, "image_size"),
        }
        if not np.any(fields["T"]):
            raise _fail(where, "T must not be zero (the cameras are at the same place)")
        for key, shape in (
            ("R1", None),
            ("R2", None),
            ("P1", (3, 4)),
            ("P2", (3, 4)),
            ("Q", (4, 4)),
        ):
            value = getattr(self, key)
            if value is not None:
                fields[key] = (
                    _check_rotation(value, where, key)
                    if shape is None
                    else _check_array(value, where, key, shape)
                )
                if key in ("P1", "P2"):
                    _check_intrinsics(fields[key][:, :3], where, f"{key}[:, :3]")
        if not isinstance(self.rectified, bool):
            raise TypeError(f"rectified must be a bool, got {self.rectified!r}")
        if not isinstance(self.source, str):
            raise TypeError(f"source must be a str, got {self.source!r}")
        if self.rectified and not (np.array_equal(fields["R"], np.eye(3)) and model == "none"):
            raise _fail(
                where, "a rectified calibration has R = identity and distortion_model 'none'"
            )
        for key, value in fields.items():
            object.__setattr__(self, key, value)

    @property
    def baseline_m(self) -> float:
        """The distance between the two camera centres, metres: the norm of T."""
        return float(np.linalg.norm(self.T))

    def to_rig(self) -> StereoRig:
        """The :class:`~stereodepth.StereoRig` of the rectified pair (focal length, baseline,
        principal point offset doffs and image size), for computing depth from disparity.

        For a rectified source (``rectified=True``): focal length K1's fx, baseline -T[0],
        doffs K2's cx - K1's cx (K1's and K2's fx, fy and cy must agree within 1e-6
        relative, as the readers require). For a source that holds the rectified
        projections P1, P2 (as OpenCV and ROS stereo calibrations do): focal length P1's fx,
        baseline -(P2[0, 3] - P1[0, 3]) / P2's fx, doffs P2's cx - P1's cx. Raises
        ValueError for any other calibration (rectify it first: the rectified pair's rig
        comes with the rectification), for a vertical pair and when the right camera is not
        to the right."""
        from ..rig import StereoRig

        where = self.source or "StereoCalibration"
        if self.rectified:
            k1, k2, t = self.K1, self.K2, self.T
            # Within the readers' tolerance (_differ: 1e-6 relative): files whose values
            # differ in the last printed digit were read,
            # rectified and given a rig by read_calibration, and refused here.
            for name, i, j in (("fx", 0, 0), ("fy", 1, 1), ("cy", 1, 2)):
                a, b = float(k1[i, j]), float(k2[i, j])
                if _differ(a, b):
                    raise _fail(
                        where,
                        f"a rectified pair has the same fx, fy and cy in K1 and K2, got {name} "
                        f"{a!r} and {b!r}",
                    )
            if abs(t[1]) > 1e-9 * abs(t[0]) or abs(t[2]) > 1e-9 * abs(t[0]):
                raise _fail(where, f"a rectified horizontal pair has T = (-B, 0, 0), got {t}")
            focal, baseline, doffs = k1[0, 0], -t[0], k2[0, 2] - k1[0, 2]
            got = f"T[0] = {float(t[0])!r} m"
        elif self.P1 is not None and self.P2 is not None:
            from ..rectify import _baseline_axis

            p1, p2 = self.P1, self.P2
            # The rectifier's rule (StereoRectifier.vertical): projections that place both
            # cameras in a third camera's frame (KITTI's P_rect_02, P_rect_03 in a ROS
            # camera_info pair) differ in P[1, 3] too, by the sub-millimetre y offsets, and
            # were refused here as a vertical pair while the rectifier took them.
            if _baseline_axis(p1, p2) == 1:
                raise _fail(
                    where,
                    "P2 is of a vertical pair (P2[1, 3] != P1[1, 3] and P2[0, 3] == "
                    "P1[0, 3]): the matchers need a horizontal one",
                )
            focal = p1[0, 0]
            baseline = -(p2[0, 3] - p1[0, 3]) / p2[0, 0]
            doffs = p2[0, 2] - p1[0, 2]
            got = f"P2[0, 3] - P1[0, 3] = {float(p2[0, 3] - p1[0, 3])!r}"
        else:
            raise _fail(
                where,
                "this calibration is not rectified and holds no P1, P2: rectify the pair "
                "first (the rectified pair's rig comes with the rectification)",
            )
        if not baseline > 0:
            # As StereoRectifier.rig's refusal: the sign convention and both remedies.
            raise _fail(
                where,
                f"the right camera must be to the right of the left one, got a baseline of "
                f"{float(baseline)!r} m ({got}; OpenCV's x2 = R @ x1 + T gives T[0] < 0 and "
                "P2[0, 3] < 0 when the left camera is first). If T's sign is wrong, negate it; "
                "if the cameras are named the other way, swap K1/K2 and D1/D2 and replace R "
                "by R.T, T by -R.T @ T",
            )
        return StereoRig.from_pixels(
            baseline_mm=float(baseline) * 1000.0,
            focal_px=float(focal),
            width_px=self.image_size[0],
            height_px=self.image_size[1],
            doffs_px=float(doffs),
        )


def _rectified_matrices(k1: np.ndarray, k2: np.ndarray, t: np.ndarray) -> dict[str, np.ndarray]:
    """R1, R2, P1, P2, Q of an already rectified horizontal pair, as cv2.stereoRectify lays
    them out (Q[3, 3] = (cx1 - cx2) / Tx keeps a principal point offset)."""
    p1 = np.hstack([k1, np.zeros((3, 1))])
    p2 = np.hstack([k2, (k2 @ t).reshape(3, 1)])
    tx = t[0]
    q = np.array(
        [
            [1.0, 0.0, 0.0, -k1[0, 2]],
            [0.0, 1.0, 0.0, -k1[1, 2]],
            [0.0, 0.0, 0.0, k1[0, 0]],
            [0.0, 0.0, -1.0 / tx, (k1[0, 2] - k2[0, 2]) / tx],
        ]
    )
    return {"R1": np.eye(3), "R2": np.eye(3), "P1": p1, "P2": p2, "Q": q}


def _rectified_calibration(
    k1: np.ndarray, k2: np.ndarray, baseline_m: float, size: tuple[int, int], where: str
) -> StereoCalibration:
    t = np.array([-baseline_m, 0.0, 0.0])
    return StereoCalibration(
        K1=k1,
        D1=np.zeros(0),
        K2=k2,
        D2=np.zeros(0),
        distortion_model="none",
        R=np.eye(3),
        T=t,
        image_size=size,
        rectified=True,
        source=where,
        **_rectified_matrices(k1, k2, t),
    )


@dataclass(frozen=True)
class Calibration:
    """A rectified rig: depth = focal_px * baseline_m / (d + doffs_px)."""

    focal_px: float
    baseline_m: float
    doffs_px: float = 0.0
    cx_px: float | None = None  # the left camera's principal point; None: the image centre
    cy_px: float | None = None
    num_disparities: int | None = None  # Middlebury's ndisp, when the file has it
    source: str = ""
    #: (width, height) of the images the file calibrates, when it says (Middlebury's width and
    #: height): images of another size need another calibration (focal length, doffs and
    #: disparities scale with the resolution). Not part of :meth:`as_dict`: it changes no result.
    image_size: tuple[int, int] | None = None

    def as_dict(self) -> dict[str, float | int | str | None]:
        return {
            "focal_px": self.focal_px,
            "baseline_m": self.baseline_m,
            "doffs_px": self.doffs_px,
            "cx_px": self.cx_px,
            "cy_px": self.cy_px,
            "num_disparities": self.num_disparities,
            "source": self.source,
        }
