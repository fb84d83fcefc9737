"""Camera drivers on their libraries' own test modes: OpenCV ``VideoCapture`` on a video file,
RealSense on a recording made with pyrealsense2's software device and ``rs.recorder`` and
played back through the same ``rs.pipeline`` a live camera uses, GenICam through harvesters and
the simulated GenTL producer shipped in the ``genicam`` package (``viky.cti``), and the image
folder with files written while it waits."""

from __future__ import annotations

import os
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest

from relcal.capture.interfaces import Camera, CaptureError, RealClock
from relcal.errors import RelcalError


def level(image: np.ndarray) -> int:
    return int(round(float(np.mean(image))))


def index(image: np.ndarray) -> int:
    """Frame k of :func:`video` (grey 10 k, give or take JPEG's rounding)."""
    return int(round(float(np.mean(image)) / 10))


# --- OpenCV -------------------------------------------------------------------------------------


@pytest.fixture
def video(tmp_path) -> Path:
    """20 frames of 64 x 48 px, frame k uniformly grey at 10 k."""
    path = tmp_path / "frames.avi"
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 30.0, (64, 48))
    for k in range(20):
        writer.write(np.full((48, 64, 3), 10 * k, np.uint8))
    writer.release()
    return path


def test_opencv_reads_frames_in_order_and_stamps_on_receipt(video):
    from relcal.capture.cameras.opencv import OpenCVCamera

    clock = RealClock()
    camera = OpenCVCamera(str(video), clock=clock, drain=False)
    assert isinstance(camera, Camera) and camera.intrinsics() is None
    before = clock.now()
    frames = [camera.grab(1.0) for _ in range(5)]
    assert [index(f.image) for f in frames] == [0, 1, 2, 3, 4]
    assert [f.sequence for f in frames] == [0, 1, 2, 3, 4]
    stamps = [f.stamp for f in frames]
    assert before <= stamps[0] and stamps == sorted(stamps) and stamps[-1] <= clock.now()
    camera.close()


def test_opencv_drains_queued_frames(video):
    """A file delivers every frame at once, as a queue full of old frames would: draining drops
    them, up to MAX_DRAIN per grab."""
    from relcal.capture.cameras.opencv import MAX_DRAIN, OpenCVCamera

    camera = OpenCVCamera(str(video), clock=RealClock())
    frame = camera.grab(1.0)
    assert frame.meta["dropped"] == MAX_DRAIN and frame.sequence == MAX_DRAIN
    assert index(frame.image) == MAX_DRAIN
    camera.grab(1.0)
    with pytest.raises(CaptureError, match="no frame"):  # the file's end
        camera.grab(1.0)
    camera.close()


def test_opencv_bad_device_and_options(tmp_path):
    from relcal.capture.cameras.opencv import OpenCVCamera

    with pytest.raises(CaptureError, match="cannot open camera"):
        OpenCVCamera(str(tmp_path / "none.avi"))
    with pytest.raises(RelcalError, match="option buffer: 0"):
        OpenCVCamera("0", buffer=0)


# --- RealSense ----------------------------------------------------------------------------------


def record_realsense(path: Path, n: int = 6) -> None:
    """A recording of a software camera: 64 x 48 BGR frames, frame k grey at 30 k, hardware
    timestamps 33.3 ms apart from 1000 ms, Brown-Conrady intrinsics."""
    rs = pytest.importorskip("pyrealsense2")
    device = rs.software_device()
    sensor = device.add_sensor("Color")
    intr = rs.intrinsics()
    intr.width, intr.height, intr.fx, intr.fy, intr.ppx, intr.ppy = 64, 48, 50, 51, 31.5, 23.5
    intr.model, intr.coeffs = rs.distortion.brown_conrady, [0.1, -0.05, 0.001, 0.002, 0.01]
    stream = rs.video_stream()
    stream.type, stream.index, stream.uid = rs.stream.color, 0, 0
    stream.width, stream.height, stream.fps, stream.bpp = 64, 48, 30, 3
    stream.fmt, stream.intrinsics = rs.format.bgr8, intr
    profile = sensor.add_video_stream(stream)
    recorder = rs.recorder(str(path), device)
    queue = rs.frame_queue(10)
    sensor.open(profile)
    sensor.start(queue)
    for k in range(n):
        frame = rs.software_video_frame()
        frame.pixels = np.full((48, 64, 3), 30 * k, np.uint8)
        frame.bpp, frame.stride = 3, 64 * 3
        frame.timestamp, frame.frame_number = 1000.0 + 33.3 * k, k
        frame.domain = rs.timestamp_domain.hardware_clock
        frame.profile = profile.as_video_stream_profile()
        sensor.on_video_frame(frame)
        time.sleep(0.03)
    sensor.stop()
    sensor.close()
    del recorder  # closes the file


def test_realsense_playback(tmp_path, monkeypatch):
    rs = pytest.importorskip("pyrealsense2")
    from relcal.capture.cameras.realsense import RealSenseCamera

    path = tmp_path / "camera.db3"  # librealsense 2.59 records ROS 2 bags (.db3)
    record_realsense(path)
    # A busy machine: half a second passes between the pipeline's start and what follows it;
    # the six frames (0.2 s of recording) must still all reach the reader.
    start = rs.pipeline.start

    def slow_start(self, *args):
        profile = start(self, *args)
        time.sleep(0.5)
        return profile

    monkeypatch.setattr(rs.pipeline, "start", slow_start)
    clock = RealClock()
    camera = RealSenseCamera(playback=str(path), clock=clock)
    assert isinstance(camera, Camera)
    intr = camera.intrinsics()
    assert (intr.fx, intr.fy, intr.cx, intr.cy, intr.width, intr.height) == (
        50,
        51,
        31.5,
        23.5,
        64,
        48,
    )
    np.testing.assert_allclose(intr.distortion, [0.1, -0.05, 0.001, 0.002, 0.01], rtol=1e-6)
    frames = [camera.grab(20.0) for _ in range(6)]
    assert [f.sequence for f in frames] == list(range(6))
    assert [level(f.image) for f in frames] == [30 * k for k in range(6)]
    assert frames[0].image.shape == (48, 64, 3) and "hardware_clock" in frames[0].meta["domain"]
    stamps = np.array([f.stamp for f in frames])
    assert (stamps <= clock.now()).all() and (np.diff(stamps) > 0).all()
    with pytest.raises(CaptureError, match="no frame within"):
        camera.grab(0.5)
    camera.close()


def test_realsense_intrinsics_conversion():
    rs = pytest.importorskip("pyrealsense2")
    from relcal.capture.cameras.realsense import to_intrinsics

    intr = rs.intrinsics()
    intr.width, intr.height, intr.fx, intr.fy, intr.ppx, intr.ppy = 640, 480, 600, 600, 320, 240
    intr.model, intr.coeffs = rs.distortion.inverse_brown_conrady, [0, 0, 0, 0, 0]
    assert to_intrinsics(rs, intr).distortion == ()  # zero coefficients: any model is none
    intr.coeffs = [0.1, 0, 0, 0, 0]
    assert to_intrinsics(rs, intr) is None  # not OpenCV's model


# --- GenICam ------------------------------------------------------------------------------------


def viky() -> str:
    genicam = pytest.importorskip("genicam")
    pytest.importorskip("harvesters")
    path = Path(genicam.__file__).parent / "viky.cti"
    if not path.is_file():
        pytest.skip("the genicam package ships no simulated producer (viky.cti)")
    return str(path)


def test_genicam_on_the_simulated_producer():
    import signal

    from relcal.capture.cameras.genicam import GenICamCamera

    clock = RealClock()
    before = signal.getsignal(signal.SIGINT)
    camera = GenICamCamera(viky(), clock=clock, device="1")  # the green Viky camera
    # harvesters' own SIGINT handler (which swallows Ctrl+C) is not left in place
    assert signal.getsignal(signal.SIGINT) is before
    try:
        assert isinstance(camera, Camera) and camera.intrinsics() is None
        before = clock.now()
        frames = [camera.grab(5.0) for _ in range(3)]
        for frame in frames:
            assert frame.image.shape == (400, 400, 3) and frame.image.dtype == np.uint8
            assert frame.meta["stamped"] == "receipt"  # Viky gives no timestamps
            assert before <= frame.stamp <= clock.now()
        sequence = [f.sequence for f in frames]
        assert sequence == sorted(sequence) and len(set(sequence)) == 3
    finally:
        camera.close()


def test_genicam_bad_options(tmp_path):
    from relcal.capture.cameras.genicam import GenICamCamera, to_image

    with pytest.raises(RelcalError, match="GenTL producer"):
        GenICamCamera(str(tmp_path / "none.cti"))
    with pytest.raises(RelcalError, match="option device: 'cam9' is none of the cameras"):
        GenICamCamera(viky(), device="cam9")
    grey = to_image(np.arange(12, dtype=np.uint8), 4, 3, "Mono8")
    assert grey.shape == (3, 4)
    rgb = to_image(np.array([1, 2, 3] * 4, np.uint8), 2, 2, "RGB8")
    assert rgb[0, 0].tolist() == [3, 2, 1]
    with pytest.raises(CaptureError, match="Mono16 is not supported"):
        to_image(np.zeros(8, np.uint8), 2, 2, "Mono16")


# --- image folder ------------------------------------------------------------------------------


def write_image(path: Path, value: int, mtime: float | None = None) -> None:
    cv2.imwrite(str(path), np.full((30, 40, 3), value, np.uint8))
    if mtime is not None:
        os.utime(path, (mtime, mtime))


def test_folder_returns_each_new_file_once_stamped_by_its_mtime(tmp_path):
    from relcal.capture.cameras.folder import FolderCamera

    write_image(tmp_path / "old.png", 5)  # before the camera opens: never returned
    clock = RealClock()
    camera = FolderCamera(str(tmp_path), clock=clock, settle=0.05)
    assert isinstance(camera, Camera)
    time.sleep(0.02)
    write_image(tmp_path / "a.png", 50)
    first = camera.grab(2.0)
    assert level(first.image) == 50 and first.meta["file"].endswith("a.png")
    age = time.time() - (tmp_path / "a.png").stat().st_mtime
    assert first.stamp == pytest.approx(clock.now() - age, abs=0.01)

    def later():
        time.sleep(0.3)
        write_image(tmp_path / "b.png", 100)

    writer = threading.Thread(target=later)
    asked = clock.now()
    writer.start()
    second = camera.grab(3.0)  # waits for the new file, not a.png again
    writer.join()
    assert level(second.image) == 100 and second.stamp > asked
    time.sleep(0.02)
    write_image(tmp_path / "a.png", 150)  # overwritten: a new image under the same name
    assert level(camera.grab(2.0).image) == 150
    with pytest.raises(CaptureError, match="no new image"):
        camera.grab(0.3)
    camera.close()


def test_folder_waits_for_a_file_being_written(tmp_path):
    from relcal.capture.cameras.folder import FolderCamera

    camera = FolderCamera(str(tmp_path), settle=0.3)
    time.sleep(0.02)
    write_image(tmp_path / "c.png", 70)
    started = time.monotonic()
    frame = camera.grab(3.0)
    assert level(frame.image) == 70 and time.monotonic() - started >= 0.25
    with pytest.raises(RelcalError, match="not a folder"):
        FolderCamera(str(tmp_path / "missing"))
