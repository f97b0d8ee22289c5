"""Robots: robot files (boards, links, devices), device plugins, and running a whole robot.

- :mod:`hwbridge.robot.plugin`: the device-plugin contract;
- :mod:`hwbridge.robot.registry`: device types by name (built in and by entry point);
- :mod:`hwbridge.robot.model` and :mod:`hwbridge.robot.config`: what a robot file says, read and
  checked with ``FILE:LINE`` errors;
- :mod:`hwbridge.robot.runtime`: ``hwbridge up`` (the bridge and every host node of a robot).
"""
