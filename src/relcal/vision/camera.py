"""Pinhole camera with OpenCV lens distortion: YAML in and out, and intrinsic calibration.

Three YAML layouts are read:

- relcal's own::

      fx: 2400.0        # px
      fy: 2400.0
      cx: 1224.0
      cy: 1024.0
      distortion: [-0.1, 0.05, 0.0, 0.0, 0.0]   # OpenCV order k1 k2 p1 p2 [k3 [k4 k5 k6 ...]]
      width: 2448       # px
      height: 2048

- ROS-Industrial robot_cal_tools: ``intrinsics: {fx, fy, cx, cy}`` (no distortion, no size);
- ROS ``camera_info`` (camera_calibration's ``ost.yaml``): ``camera_matrix.data``,
  ``distortion_coefficients.data``, ``image_width``, ``image_height``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any, Literal

import cv2
import numpy as np
import pydantic

from relcal.errors import RelcalError
from relcal.io import load_yaml, validate, write_text, yaml_text

DistortionModel = Literal["none", "radial", "radial_tangential", "plumb_bob"]
_N_DIST = {"none": 0, "radial": 2, "radial_tangential": 4, "plumb_bob": 5}


@dataclass(frozen=True)
class Camera:
    """Pinhole intrinsics (px) and OpenCV distortion coefficients.

    ``distortion`` is empty (no distortion) or 4, 5, 8, 12 or 14 coefficients in OpenCV order
    ``(k1, k2, p1, p2[, k3[, k4, k5, k6[, s1, s2, s3, s4[, tx, ty]]]])``. ``width`` and
    ``height`` (px) may be unknown (``None``) when a file does not give them.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    distortion: tuple[float, ...] = ()
    width: int | None = None
    height: int | None = None

    def __post_init__(self) -> None:
        for name in ("fx", "fy", "cx", "cy"):
            object.__setattr__(self, name, float(getattr(self, name)))
        for name in ("width", "height"):
            if getattr(self, name) is not None:
                object.__setattr__(self, name, int(getattr(self, name)))
        object.__setattr__(self, "distortion", tuple(float(k) for k in self.distortion))
        if len(self.distortion) not in (0, 4, 5, 8, 12, 14):
            raise ValueError(
                f"distortion needs 0, 4, 5, 8, 12 or 14 coefficients, got {len(self.distortion)}"
            )
        if not (self.fx > 0 and self.fy > 0):
            raise ValueError(f"focal lengths must be positive, got fx={self.fx}, fy={self.fy}")

    def scaled(self, factor: float) -> Camera:
        """The same lens and field of view on a sensor of ``factor`` times the resolution
        (``factor`` 0.5: pixels binned 2 x 2). Focal lengths scale, the principal point maps
        pixel centres (``(c + 0.5) f - 0.5``), distortion (in normalised coordinates) stays.
        The image size, when known, is rounded to whole pixels."""
        if factor == 1:
            return self
        size = {
            name: max(1, round(getattr(self, name) * factor))
            for name in ("width", "height")
            if getattr(self, name) is not None
        }
        return replace(
            self,
            fx=self.fx * factor,
            fy=self.fy * factor,
            cx=(self.cx + 0.5) * factor - 0.5,
            cy=(self.cy + 0.5) * factor - 0.5,
            **size,
        )

    @property
    def matrix(self) -> np.ndarray:
        """Camera matrix ``K`` ``(3, 3)``."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @property
    def dist(self) -> np.ndarray:
        """Distortion coefficients as OpenCV wants them, shape ``(D,)`` (``(5,)`` zeros if none)."""
        return np.asarray(self.distortion, float) if self.distortion else np.zeros(5)

    @property
    def size(self) -> tuple[int, int]:
        """``(width, height)`` in px; raises when unknown."""
        if self.width is None or self.height is None:
            raise RelcalError("the camera's image size (width, height) is not known")
        return self.width, self.height

    def with_size(self, width: int, height: int) -> Camera:
        """The same camera with the image size set (px)."""
        return replace(self, width=int(width), height=int(height))

    def project(self, points_camera: np.ndarray) -> np.ndarray:
        """Pixels ``(N, 2)`` of points ``(N, 3)`` given in the camera frame (m)."""
        pts = np.asarray(points_camera, float).reshape(-1, 1, 3)
        uv, _ = cv2.projectPoints(pts, np.zeros(3), np.zeros(3), self.matrix, self.dist)
        return uv.reshape(-1, 2)

    def undistort(self, pixels: np.ndarray) -> np.ndarray:
        """Normalised image coordinates ``(N, 2)`` (x/z, y/z) of pixels ``(N, 2)``."""
        pts = np.asarray(pixels, np.float64).reshape(-1, 1, 2)
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 50, 1e-12)
        out = cv2.undistortPoints(pts, self.matrix, self.dist, criteria=criteria)
        return out.reshape(-1, 2)

    def to_dict(self) -> dict[str, Any]:
        """relcal's YAML mapping of this camera."""
        out: dict[str, Any] = {
            "fx": float(self.fx),
            "fy": float(self.fy),
            "cx": float(self.cx),
            "cy": float(self.cy),
            "distortion": [float(k) for k in self.distortion],
        }
        if self.width is not None and self.height is not None:
            out["width"] = int(self.width)
            out["height"] = int(self.height)
        return out


# ----------------------------------------------------------------------------- YAML


class CameraSpec(pydantic.BaseModel):
    """relcal's camera YAML (px)."""

    model_config = pydantic.ConfigDict(extra="forbid")

    fx: pydantic.PositiveFloat
    fy: pydantic.PositiveFloat
    cx: float
    cy: float
    distortion: list[float] = pydantic.Field(default_factory=list)
    width: pydantic.PositiveInt | None = None
    height: pydantic.PositiveInt | None = None

    @pydantic.field_validator("distortion")
    @classmethod
    def _count(cls, value: list[float]) -> list[float]:
        if len(value) not in (0, 4, 5, 8, 12, 14):
            raise ValueError(
                f"expected 0, 4, 5, 8, 12 or 14 OpenCV coefficients (k1 k2 p1 p2 [k3 ...]), "
                f"got {len(value)}"
            )
        return value

    @pydantic.model_validator(mode="after")
    def _size(self) -> CameraSpec:
        if (self.width is None) != (self.height is None):
            raise ValueError("give both width and height (px) or neither")
        return self

    def to_camera(self) -> Camera:
        return Camera(
            self.fx, self.fy, self.cx, self.cy, tuple(self.distortion), self.width, self.height
        )


class _RctIntrinsics(pydantic.BaseModel):
    fx: pydantic.PositiveFloat
    fy: pydantic.PositiveFloat
    cx: float
    cy: float


class _RctCameraFile(pydantic.BaseModel):
    intrinsics: _RctIntrinsics
    distortion: list[float] = pydantic.Field(default_factory=list)
    width: pydantic.PositiveInt | None = None
    height: pydantic.PositiveInt | None = None


class _RosMatrix(pydantic.BaseModel):
    rows: int | None = None
    cols: int | None = None
    data: list[float]


class _RosCameraInfo(pydantic.BaseModel):
    image_width: pydantic.PositiveInt | None = None
    image_height: pydantic.PositiveInt | None = None
    camera_matrix: _RosMatrix
    distortion_model: str | None = None
    distortion_coefficients: _RosMatrix | None = None

    @pydantic.field_validator("camera_matrix")
    @classmethod
    def _nine(cls, value: _RosMatrix) -> _RosMatrix:
        if len(value.data) != 9:
            raise ValueError(
                f"camera_matrix.data needs 9 numbers (3x3 row-major), got {len(value.data)}"
            )
        return value


def load_camera(path: str | Path, width: int | None = None, height: int | None = None) -> Camera:
    """Read a camera from YAML (relcal, robot_cal_tools or ROS ``camera_info`` layout).

    ``width``/``height`` (px) fill in the image size when the file does not give it.

    Raises
    ------
    RelcalError
        Naming the file, line and field when the file is not a usable camera description.
    """
    data, node = load_yaml(path)
    if not isinstance(data, dict) or not ({"fx", "intrinsics", "camera_matrix"} & set(data)):
        raise RelcalError(
            f"{path}: not a camera file (expected a mapping with fx, fy, cx, cy, or "
            "'intrinsics:' or ROS's 'camera_matrix:')"
        )
    if "intrinsics" in data:
        rct = validate(_RctCameraFile, data, path, node)
        k = rct.intrinsics
        camera = _checked(path, k.fx, k.fy, k.cx, k.cy, rct.distortion, rct.width, rct.height)
    elif "camera_matrix" in data:
        ros = validate(_RosCameraInfo, data, path, node)
        m = ros.camera_matrix.data
        dist = ros.distortion_coefficients.data if ros.distortion_coefficients else []
        if dist and not any(dist):
            dist = []
        model = (ros.distortion_model or "plumb_bob").lower()
        if model not in ("plumb_bob", "rational_polynomial"):
            raise RelcalError(
                f"{path}: distortion_model: '{model}' is not supported (plumb_bob or "
                f"rational_polynomial)"
            )
        camera = _checked(path, m[0], m[4], m[2], m[5], dist, ros.image_width, ros.image_height)
    else:
        camera = validate(CameraSpec, data, path, node).to_camera()
    if camera.width is None and width is not None and height is not None:
        camera = camera.with_size(width, height)
    return camera


def _checked(
    path: str | Path,
    fx: float,
    fy: float,
    cx: float,
    cy: float,
    dist: Sequence[float],
    width: int | None,
    height: int | None,
) -> Camera:
    try:
        return Camera(fx, fy, cx, cy, tuple(dist), width, height)
    except ValueError as exc:
        raise RelcalError(f"{path}: {exc}") from None


def save_camera(camera: Camera, path: str | Path) -> None:
    """Write a camera in relcal's YAML layout (atomically)."""
    write_text(path, yaml_text(camera.to_dict()))


# ----------------------------------------------------------------------------- calibration


@dataclass(frozen=True)
class IntrinsicsResult:
    """Outcome of :func:`calibrate_intrinsics`.

    ``per_image_rms`` ``(N,)`` (px) is aligned with the input detections (from the last fit that
    included the frame; NaN for frames rejected before any fit); ``rejected`` maps an input index
    to the reason it was left out; ``std`` holds the standard deviations of fx, fy, cx, cy (px).
    """

    camera: Camera
    rms: float
    per_image_rms: np.ndarray
    used: tuple[int, ...]
    rejected: dict[int, str] = field(default_factory=dict)
    std: dict[str, float] = field(default_factory=dict)


def _flags(model: DistortionModel, fix_aspect: bool, fix_principal: bool) -> int:
    flags = 0
    n = _N_DIST[model]
    if n < 5:
        flags |= cv2.CALIB_FIX_K3
    if n < 4:
        flags |= cv2.CALIB_ZERO_TANGENT_DIST
    if n < 2:
        flags |= cv2.CALIB_FIX_K1 | cv2.CALIB_FIX_K2
    if fix_aspect:
        flags |= cv2.CALIB_FIX_ASPECT_RATIO
    if fix_principal:
        flags |= cv2.CALIB_FIX_PRINCIPAL_POINT
    return flags


def calibrate_intrinsics(
    detections: Sequence[Any],
    image_size: tuple[int, int] | None = None,
    *,
    model: DistortionModel = "plumb_bob",
    min_points: int = 8,
    min_views: int = 4,
    outlier_ratio: float = 3.0,
    outlier_floor: float = 0.5,
    fix_aspect: bool = False,
    fix_principal: bool = False,
) -> IntrinsicsResult:
    """Calibrate intrinsics and distortion with OpenCV from board detections.

    Frames are dropped one at a time, worst first, while the worst per-image RMS exceeds both
    ``outlier_ratio`` times the median and ``outlier_floor`` px; each drop is recorded with its
    reason, then the camera is refitted.

    Parameters
    ----------
    detections : sequence of :class:`relcal.vision.detect.Detection`
        One per image, all from the same camera and board.
    image_size : (width, height) or None
        Image size in px (default: from the detections).
    model : {"none", "radial", "radial_tangential", "plumb_bob"}
        Distortion coefficients estimated: none, k1 k2, k1 k2 p1 p2, or k1 k2 p1 p2 k3.
    min_points : int
        Frames with fewer points are rejected up front.
    min_views : int
        Fewer usable frames than this raises :class:`RelcalError`.

    Returns
    -------
    IntrinsicsResult
    """
    n = len(detections)
    if image_size is None:
        if n == 0:
            raise RelcalError("intrinsic calibration needs detections; none were given")
        image_size = tuple(detections[0].image_size)
    rejected: dict[int, str] = {}
    for i, det in enumerate(detections):
        if len(det.ids) < min_points:
            rejected[i] = f"only {len(det.ids)} points (calibration needs {min_points})"
        elif tuple(det.image_size) != tuple(image_size):
            rejected[i] = f"image size {tuple(det.image_size)} differs from {tuple(image_size)}"
    used = [i for i in range(n) if i not in rejected]
    per_image = np.full(n, np.nan)
    flags = _flags(model, fix_aspect, fix_principal)
    while True:
        if len(used) < min_views:
            reasons = "; ".join(f"frame {i}: {r}" for i, r in sorted(rejected.items()))
            raise RelcalError(
                f"intrinsic calibration needs at least {min_views} usable views, have "
                f"{len(used)}" + (f" ({reasons})" if reasons else "")
            )
        obj = [detections[i].object_points.astype(np.float32).reshape(-1, 1, 3) for i in used]
        img = [detections[i].image_points.astype(np.float32).reshape(-1, 1, 2) for i in used]
        w, h = image_size
        k0 = np.array([[max(w, h), 0, w / 2 - 0.5], [0, max(w, h), h / 2 - 0.5], [0, 0, 1.0]])
        criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
        rms, k, dist, _, _, std_in, _, errors = cv2.calibrateCameraExtended(
            obj, img, (int(w), int(h)), k0, np.zeros(5), flags=flags, criteria=criteria
        )
        errors = np.ravel(errors)
        per_image[used] = errors
        median = float(np.median(errors))
        worst = int(np.argmax(errors))
        limit = max(outlier_ratio * median, outlier_floor)
        if errors[worst] <= limit or len(used) <= min_views:
            break
        idx = used.pop(worst)
        rejected[idx] = (
            f"reprojection RMS {errors[worst]:.3f} px is {errors[worst] / median:.1f}x the "
            f"median {median:.3f} px (limit {limit:.3f} px)"
        )
    dist = np.ravel(dist)[:5] if model != "none" else ()
    camera = Camera(k[0, 0], k[1, 1], k[0, 2], k[1, 2], tuple(dist), int(w), int(h))
    std_in = np.ravel(std_in)
    std = {name: float(std_in[i]) for i, name in enumerate(("fx", "fy", "cx", "cy"))}
    return IntrinsicsResult(camera, float(rms), per_image, tuple(used), rejected, std)
