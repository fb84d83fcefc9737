"""Cameras OpenCV's ``VideoCapture`` opens: UVC webcams (V4L2), GStreamer pipelines, the GigE
and USB3 cameras of OpenCV's backends, and video files (for tests).

``VideoCapture`` queues frames in the driver (V4L2 keeps several buffers): a frame read late was
exposed long before. The buffer is set to ``buffer`` frames, and each :meth:`grab` first drains
what is already queued: a frame that arrives faster than half a frame period was waiting in the
queue, so it is dropped, until one arrives that the device had to deliver. That frame is stamped
on receipt (``VideoCapture`` gives no exposure time on every backend).
"""

from __future__ import annotations

import numpy as np

from relcal.capture.interfaces import CaptureError, Clock, Frame, RealClock
from relcal.errors import RelcalError
from relcal.vision.camera import Camera as Intrinsics

MAX_DRAIN = 8  # queued frames dropped at most per grab


class OpenCVCamera:
    """A ``cv2.VideoCapture`` source.

    Parameters
    ----------
    device : str
        A device index (``0``), a device path (``/dev/video2``), a GStreamer pipeline or a video
        file.
    clock : Clock
        The capture loop's clock.
    width, height : int, optional
        Requested frame size, px.
    fps : float, optional
        Requested frame rate, Hz.
    buffer : int
        Frames the driver may queue (``CAP_PROP_BUFFERSIZE``; not every backend honours it).
    drain : bool
        Drop the frames queued before each grab (see the module's description); off for video
        files, whose frames all arrive at once.
    intrinsics : str, optional
        A camera YAML file (:func:`relcal.vision.camera.load_camera`) with this camera's
        intrinsics; OpenCV cannot tell them.
    """

    def __init__(
        self,
        device: str = "0",
        *,
        clock: Clock | None = None,
        width: int | None = None,
        height: int | None = None,
        fps: float | None = None,
        buffer: int = 1,
        drain: bool = True,
        intrinsics: str | None = None,
    ) -> None:
        import cv2

        self._cv2 = cv2
        for name, value in (("width", width), ("height", height), ("fps", fps), ("buffer", buffer)):
            if value is not None and value <= 0:
                raise RelcalError(f"opencv option {name}: {value}: expected a positive number")
        self._clock = clock or RealClock()
        source: int | str = int(device) if str(device).isdigit() else str(device)
        self._cap = cv2.VideoCapture(source)
        if not self._cap.isOpened():
            raise CaptureError(
                f"opencv: cannot open camera '{device}' (the index or path of a video device, a "
                "GStreamer pipeline or a video file; is it plugged in and not used by another "
                "program?)"
            )
        for prop, value in (
            (cv2.CAP_PROP_FRAME_WIDTH, width),
            (cv2.CAP_PROP_FRAME_HEIGHT, height),
            (cv2.CAP_PROP_FPS, fps),
            (cv2.CAP_PROP_BUFFERSIZE, buffer),
        ):
            if value is not None:
                self._cap.set(prop, float(value))
        rate = fps or self._cap.get(cv2.CAP_PROP_FPS)
        self._period = 1.0 / rate if rate and rate > 0 else 1.0 / 30.0
        self._drain = drain
        self._intrinsics: Intrinsics | None = None
        if intrinsics:
            from relcal.vision.camera import load_camera

            self._intrinsics = load_camera(intrinsics)
        self._count = 0

    def grab(self, timeout: float) -> Frame:
        """The next frame the device delivers after the queued ones, stamped on receipt.

        Raises
        ------
        CaptureError
            No frame (a disconnected camera, the end of a video file), or none within
            ``timeout`` seconds.
        """
        start = self._clock.now()
        for dropped in range(MAX_DRAIN + 1):
            asked = self._clock.now()
            if not self._cap.grab():
                raise CaptureError("opencv: the camera delivered no frame (disconnected?)")
            received = self._clock.now()
            self._count += 1
            waited = received - asked
            if not self._drain or waited >= 0.5 * self._period or dropped == MAX_DRAIN:
                break
            if received - start > timeout:
                break
        if received - start > timeout:
            raise CaptureError(f"opencv: no frame within {timeout:g} s")
        ok, image = self._cap.retrieve()
        if not ok or image is None:
            raise CaptureError("opencv: the camera delivered an empty frame")
        return Frame(
            image=np.ascontiguousarray(image),
            stamp=received,
            sequence=self._count - 1,
            meta={"dropped": dropped if self._drain else 0},
        )

    def intrinsics(self) -> Intrinsics | None:
        """The intrinsics given with ``intrinsics=`` (OpenCV does not know them), else None."""
        return self._intrinsics

    def close(self) -> None:
        self._cap.release()
