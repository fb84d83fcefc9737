"""Images another program writes into a folder (a vendor's acquisition tool, a script on another
computer sharing the folder): each new image file is one frame.

Only files that appear after the camera is opened count (those already there are from an earlier
run). :meth:`FolderCamera.grab` returns the oldest file not returned before, once its size has
not changed for ``settle`` seconds (the writer is done with it), stamped with its modification
time (when the writer finished, the nearest to the exposure a folder can tell) on the loop clock.
A file is identified by its name, size and modification time: the same file is never returned
twice, and one overwritten with a new image counts as new.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

import numpy as np

from relcal.capture.interfaces import CaptureError, Clock, Frame, RealClock
from relcal.errors import RelcalError
from relcal.vision.camera import Camera as Intrinsics

SUFFIXES = (".png", ".jpg", ".jpeg", ".bmp", ".tif", ".tiff", ".pgm", ".ppm")
POLL = 0.05  # s between two looks at the folder


class FolderCamera:
    """New image files in ``path``.

    Parameters
    ----------
    path : str
        The folder the other program writes into.
    clock : Clock
        The capture loop's clock.
    settle : float
        Seconds a file's size must stay unchanged before it is read.
    intrinsics : str, optional
        A camera YAML file with the camera's intrinsics.
    """

    def __init__(
        self,
        path: str,
        *,
        clock: Clock | None = None,
        settle: float = 0.2,
        intrinsics: str | None = None,
    ) -> None:
        self.path = Path(path)
        if not self.path.is_dir():
            raise RelcalError(f"folder option path: {path}: not a folder")
        self._clock = clock or RealClock()
        self.settle = float(settle)
        self._opened_ns = time.time_ns()
        self._seen: set[tuple[str, int, int]] = set()
        self._intrinsics: Intrinsics | None = None
        if intrinsics:
            from relcal.vision.camera import load_camera

            self._intrinsics = load_camera(intrinsics)

    def _candidates(self) -> list[tuple[int, str, int]]:
        """``(mtime_ns, name, size)`` of the new image files, oldest first."""
        found = []
        with os.scandir(self.path) as entries:
            for entry in entries:
                if not entry.is_file() or Path(entry.name).suffix.lower() not in SUFFIXES:
                    continue
                if entry.name.startswith("."):  # a writer's temporary file
                    continue
                info = entry.stat()
                key = (entry.name, info.st_size, info.st_mtime_ns)
                if info.st_mtime_ns >= self._opened_ns and key not in self._seen:
                    found.append((info.st_mtime_ns, entry.name, info.st_size))
        return sorted(found)

    def grab(self, timeout: float) -> Frame:
        """The oldest new image file, once complete, stamped with its modification time.

        Raises
        ------
        CaptureError
            No new complete image within ``timeout`` seconds.
        """
        import cv2

        start = self._clock.now()
        while True:
            for _mtime, name, size in self._candidates():
                file = self.path / name
                try:
                    info = file.stat()
                except FileNotFoundError:
                    continue
                age = time.time() - info.st_mtime_ns * 1e-9
                if info.st_size != size or age < self.settle or info.st_size == 0:
                    continue  # still being written
                key = (name, info.st_size, info.st_mtime_ns)
                self._seen.add(key)
                image = cv2.imread(str(file), cv2.IMREAD_UNCHANGED)
                if image is None:
                    continue  # not an image after all (skipped for good)
                if image.dtype != np.uint8:
                    image = cv2.convertScaleAbs(image, alpha=255.0 / max(int(image.max()), 1))
                if image.ndim == 3 and image.shape[2] == 4:
                    image = cv2.cvtColor(image, cv2.COLOR_BGRA2BGR)
                stamp = self._clock.now() - (time.time() - info.st_mtime_ns * 1e-9)
                return Frame(image=image, stamp=stamp, meta={"file": str(file)})
            if self._clock.now() - start > timeout:
                raise CaptureError(
                    f"folder: no new image in {self.path} within {timeout:g} s (is the other "
                    "program writing there?)"
                )
            self._clock.sleep(POLL)

    def intrinsics(self) -> Intrinsics | None:
        """The intrinsics given with ``intrinsics=``, else None."""
        return self._intrinsics

    def close(self) -> None:
        pass
