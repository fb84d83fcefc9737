"""Capture: move the robot through a plan, wait until it is still, take a fresh image, record.

The loop (:mod:`relcal.capture.loop`) talks to a robot and a camera only through the small
interfaces of :mod:`relcal.capture.interfaces`; drivers for real devices and the virtual cell
implement them.
"""
