"""GenICam cameras (GigE Vision, USB3 Vision, CoaXPress, ...) through ``harvesters`` and the GenTL
producer of the camera's vendor (``pip install 'relcal[genicam]'``; the producer is a ``.cti``
file from the vendor's SDK, e.g. Basler pylon, Allied Vision Vimba X, Teledyne Spinnaker, MATRIX
VISION mvIMPACT Acquire).

Frames are copied out of the producer's buffer before it is queued again. Each is stamped with the
buffer's device timestamp (``timestamp_ns``) mapped to the loop clock by
:class:`~relcal.capture.timesync.ClockMap` where the producer gives one, else on receipt; its
``frame_id`` is the sequence. Colour, mono and Bayer 8-bit pixel formats are turned into BGR or
grey images.
"""

from __future__ import annotations

import signal
import threading
from pathlib import Path

import numpy as np

from relcal.capture.interfaces import CaptureError, Clock, Frame, RealClock
from relcal.capture.timesync import ClockMap, require
from relcal.errors import RelcalError
from relcal.vision.camera import Camera as Intrinsics

# GenICam pixel format -> (channels, OpenCV conversion to BGR or None for grey / BGR already)
BAYER = {"BayerRG8": "COLOR_BayerRG2BGR", "BayerGR8": "COLOR_BayerGR2BGR",
         "BayerBG8": "COLOR_BayerBG2BGR", "BayerGB8": "COLOR_BayerGB2BGR"}  # fmt: skip
COLOUR = {"RGB8": (3, "COLOR_RGB2BGR"), "BGR8": (3, None), "RGBa8": (4, "COLOR_RGBA2BGR"),
          "BGRa8": (4, "COLOR_BGRA2BGR"), "Mono8": (1, None)}  # fmt: skip


def to_image(data: np.ndarray, width: int, height: int, pixel_format: str) -> np.ndarray:
    """A BGR ``(H, W, 3)`` or grey ``(H, W)`` uint8 image from a GenICam buffer's 8-bit data."""
    import cv2

    if pixel_format in BAYER:
        return cv2.cvtColor(data.reshape(height, width), getattr(cv2, BAYER[pixel_format]))
    if pixel_format not in COLOUR:
        raise CaptureError(
            f"genicam: pixel format {pixel_format} is not supported; set the camera to one of "
            f"{', '.join([*COLOUR, *BAYER])} (option pixel_format)"
        )
    channels, code = COLOUR[pixel_format]
    image = data.reshape(height, width, channels) if channels > 1 else data.reshape(height, width)
    return cv2.cvtColor(image, getattr(cv2, code)) if code else image.copy()


class GenICamCamera:
    """A GenICam camera behind a GenTL producer.

    Parameters
    ----------
    cti : str
        The GenTL producer file (``.cti``).
    clock : Clock
        The capture loop's clock.
    device : str
        Which camera: its serial number, its id, or its index among those the producer lists
        (default ``0``).
    pixel_format : str, optional
        Set the camera's ``PixelFormat`` node (e.g. ``BayerRG8``, ``Mono8``) before starting.
    """

    def __init__(
        self,
        cti: str,
        *,
        clock: Clock | None = None,
        device: str = "0",
        pixel_format: str | None = None,
    ) -> None:
        core = require("harvesters.core", "genicam", "the GenICam camera")
        if not Path(cti).is_file():
            raise RelcalError(
                f"genicam option cti: {cti}: file not found; expected the GenTL producer (.cti) "
                "installed with the camera vendor's SDK"
            )
        self._clock = clock or RealClock()
        self._map = ClockMap(self._clock)
        self._harvester = core.Harvester()
        self._harvester.add_file(str(cti))
        self._harvester.update()
        found = self._harvester.device_info_list
        if not found:
            self._harvester.reset()
            raise CaptureError(f"genicam: the producer {cti} finds no camera")
        key = self._search_key(str(device), found)
        # harvesters replaces the SIGINT handler with one that destroys the acquirer and swallows
        # the interrupt: the capture loop's own handling of Ctrl+C is put back
        main = threading.current_thread() is threading.main_thread()
        sigint = signal.getsignal(signal.SIGINT) if main else None
        try:
            self._acquirer = self._harvester.create(key)
        except Exception as exc:
            self._harvester.reset()
            raise CaptureError(f"genicam: cannot open camera '{device}': {exc}") from None
        finally:
            if main and sigint is not None:
                signal.signal(signal.SIGINT, sigint)
        nodes = self._acquirer.remote_device.node_map
        if pixel_format:
            try:
                nodes.PixelFormat.value = pixel_format
            except Exception as exc:
                self.close()
                raise RelcalError(
                    f"genicam option pixel_format: '{pixel_format}' refused by the camera ({exc})"
                ) from None
        self._acquirer.start()

    @staticmethod
    def _search_key(device: str, found: list) -> int | dict[str, str]:
        for info in found:
            if device in (info.serial_number, info.id_):
                return {"serial_number": info.serial_number}
        if device.isdigit() and int(device) < len(found):
            return int(device)
        listed = ", ".join(f"{i.id_} (serial {i.serial_number})" for i in found)
        raise RelcalError(f"genicam option device: '{device}' is none of the cameras: {listed}")

    def grab(self, timeout: float) -> Frame:
        """The next frame the producer delivers, copied out of its buffer.

        Raises
        ------
        CaptureError
            No frame within ``timeout`` seconds.
        """
        try:
            buffer = self._acquirer.fetch(timeout=timeout)
        except Exception as exc:  # harvesters raises genicam's TimeoutException and others
            raise CaptureError(f"genicam: no frame within {timeout:g} s ({exc})") from None
        received = self._clock.now()
        try:
            part = buffer.payload.components[0]
            image = to_image(part.data, part.width, part.height, part.data_format)
            try:
                device_ns = int(buffer.timestamp_ns)
            except Exception:  # the producer has no timestamps
                device_ns = 0
            try:
                sequence = int(buffer.frame_id)
            except Exception:
                sequence = None
        finally:
            buffer.queue()
        stamp = self._map.observe(device_ns * 1e-9, received) if device_ns else received
        meta = {"stamped": "device" if device_ns else "receipt"}
        return Frame(image=image, stamp=stamp, sequence=sequence, meta=meta)

    def intrinsics(self) -> Intrinsics | None:
        """GenICam cameras do not store intrinsics: None (calibrate them or give a file)."""
        return None

    def close(self) -> None:
        acquirer = getattr(self, "_acquirer", None)
        if acquirer is not None:
            acquirer.stop()
            acquirer.destroy()
            self._acquirer = None
        self._harvester.reset()
