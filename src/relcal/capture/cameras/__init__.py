"""Camera drivers for the capture loop, one module per family (:mod:`relcal.capture.devices`
names them):

- :mod:`~relcal.capture.cameras.opencv`: OpenCV ``VideoCapture`` (UVC webcams, V4L2, GStreamer
  pipelines, GigE cameras OpenCV's backends open, video files);
- :mod:`~relcal.capture.cameras.realsense`: Intel RealSense through ``pyrealsense2`` (extra
  ``realsense``), also playing back recorded ``.bag`` files;
- :mod:`~relcal.capture.cameras.genicam`: GenICam cameras through ``harvesters`` and a GenTL
  producer (``.cti``) (extra ``genicam``);
- :mod:`~relcal.capture.cameras.folder`: images another program writes into a folder.
"""
