"""Robot drivers for the capture loop, one module per family, each around a maintained library
imported only when the driver is opened (:mod:`relcal.capture.devices` names them):

- :mod:`~relcal.capture.robots.ur`: Universal Robots through ``ur_rtde`` (extra ``ur``);
- :mod:`~relcal.capture.robots.franka`: Franka Research 3 / Panda through ``franky`` (extra
  ``franka``);
- :mod:`~relcal.capture.robots.ros`: any ros2_control robot through rosbridge and ``roslibpy``
  (extra ``ros``): ``/joint_states`` and a ``FollowJointTrajectory`` action;
- :mod:`~relcal.capture.robots.manual`: any robot, jogged by the operator.
"""
