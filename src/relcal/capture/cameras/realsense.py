"""Intel RealSense cameras through ``pyrealsense2`` (``pip install 'relcal[realsense]'``).

One stream (colour by default, or an infrared imager: sharper corners, no rolling shutter on the
D400's global-shutter imagers) through an ``rs.pipeline``. Each frame is stamped with its device
timestamp (``get_timestamp``, ms, in the frame's timestamp domain: the camera's hardware clock,
or the host-synchronised global time) mapped to the loop clock by
:class:`~relcal.capture.timesync.ClockMap`; ``get_frame_number`` is its sequence. The intrinsics
are the stream profile's, which the camera stores from its factory calibration. A recording
(``playback=`` a ``.bag`` or ``.db3`` file from the RealSense Viewer or ``rs.recorder``) plays
back through the same code, frame by frame.
"""

from __future__ import annotations

import numpy as np

from relcal.capture.interfaces import CaptureError, Clock, Frame, RealClock
from relcal.capture.timesync import ClockMap, require
from relcal.errors import RelcalError
from relcal.vision.camera import Camera as Intrinsics

STREAMS = ("color", "infrared")


def to_intrinsics(rs, intr) -> Intrinsics | None:
    """relcal's camera from an ``rs.intrinsics``: Brown-Conrady coefficients are OpenCV's
    ``k1, k2, p1, p2, k3``; another model with non-zero coefficients has no OpenCV equivalent
    (``None``: give the intrinsics another way)."""
    coeffs = tuple(float(c) for c in intr.coeffs[:5])
    if intr.model != rs.distortion.brown_conrady and any(coeffs):
        return None
    return Intrinsics(
        fx=intr.fx,
        fy=intr.fy,
        cx=intr.ppx,
        cy=intr.ppy,
        distortion=coeffs if any(coeffs) else (),
        width=intr.width,
        height=intr.height,
    )


class RealSenseCamera:
    """A RealSense camera (or a recording of one).

    Parameters
    ----------
    serial : str, optional
        The camera's serial number (default: the first one found).
    clock : Clock
        The capture loop's clock.
    stream : {"color", "infrared"}
        Which stream to take (infrared: the left imager, 8-bit grey).
    width, height : int
        Frame size, px.
    fps : int
        Frame rate, Hz.
    playback : str, optional
        A recording (``.bag``/``.db3``) to play back instead of a live camera.
    """

    def __init__(
        self,
        serial: str | None = None,
        *,
        clock: Clock | None = None,
        stream: str = "color",
        width: int = 1280,
        height: int = 720,
        fps: int = 30,
        playback: str | None = None,
    ) -> None:
        rs = self._rs = require("pyrealsense2", "realsense", "the RealSense camera")
        if stream not in STREAMS:
            raise RelcalError(f"realsense option stream: '{stream}': expected color or infrared")
        self._clock = clock or RealClock()
        self._map = ClockMap(self._clock)
        self._stream = stream
        config = rs.config()
        if playback:
            config.enable_device_from_file(str(playback), repeat_playback=False)
        else:
            if serial:
                config.enable_device(str(serial))
            if stream == "color":
                config.enable_stream(rs.stream.color, width, height, rs.format.bgr8, fps)
            else:
                config.enable_stream(rs.stream.infrared, 1, width, height, rs.format.y8, fps)
        self._pipeline = rs.pipeline()
        try:
            if playback:
                # Frame by frame, waiting for the reader, from the first frame: set after the
                # start, the recording played in real time meanwhile, and on a busy machine a
                # short one dropped its frames before the first grab (the pipeline starts the
                # device that the config resolves to, so it is set here).
                config.resolve(self._pipeline).get_device().as_playback().set_real_time(False)
            profile = self._pipeline.start(config)
        except RuntimeError as exc:
            where = f"recording {playback}" if playback else f"camera {serial or '(first)'}"
            raise CaptureError(f"realsense: cannot start {where}: {exc}") from None
        kind = rs.stream.color if stream == "color" else rs.stream.infrared
        try:
            self._profile = profile.get_stream(kind).as_video_stream_profile()
        except RuntimeError:
            self._pipeline.stop()
            raise CaptureError(f"realsense: the device has no {stream} stream") from None

    def grab(self, timeout: float) -> Frame:
        """The next frame, stamped with its device timestamp on the loop clock.

        Raises
        ------
        CaptureError
            No frame within ``timeout`` seconds (or the recording's end).
        """
        rs = self._rs
        ok, frames = self._pipeline.try_wait_for_frames(int(max(timeout, 0.001) * 1000))
        received = self._clock.now()
        if not ok:
            raise CaptureError(f"realsense: no frame within {timeout:g} s")
        frame = frames.get_color_frame() if self._stream == "color" else frames.get_infrared_frame()
        if not frame:
            raise CaptureError(f"realsense: a frameset without a {self._stream} frame")
        image = np.array(frame.get_data(), copy=True)
        fmt = frame.get_profile().format()
        if fmt == rs.format.rgb8:
            image = image[..., ::-1].copy()
        stamp = self._map.observe(frame.get_timestamp() / 1000.0, received)
        return Frame(
            image=image,
            stamp=stamp,
            sequence=int(frame.get_frame_number()),
            meta={"domain": str(frame.get_frame_timestamp_domain())},
        )

    def intrinsics(self) -> Intrinsics | None:
        """The stream profile's intrinsics (the camera's factory calibration)."""
        return to_intrinsics(self._rs, self._profile.get_intrinsics())

    def close(self) -> None:
        self._pipeline.stop()
