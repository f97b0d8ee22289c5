"""Gateways from the hwbridge graph into ROS graphs.

- :mod:`hwbridge.gateway.ros2`: ``hwbridge ros2``, through rclpy (the ``[ros2]`` extra); ROS 1
  bytes become CDR with rosbags (:mod:`hwbridge.gateway.types`).
- :mod:`hwbridge.gateway.ros1`: ``hwbridge ros1``, a ROS 1 node in pure Python
  (:mod:`hwbridge.gateway.tcpros`) passing ROS 1 bytes through unchanged.
- :mod:`hwbridge.gateway.common`: choosing names, watching the graph, reporting once.
- :mod:`hwbridge.gateway.launch`: a gateway as a child of ``hwbridge up --ros2/--ros1``.

Importing this package imports neither rclpy nor Zenoh.
"""
