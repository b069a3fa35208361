"""The m4k ROS 2 bridge: the only rclpy code of the stack (see :mod:`m4k_rt.bridge.node`).

Modules: ``node`` (the ``m4k_bridge`` node and ``main``), ``params`` (parameter table and
pure validation), ``convert`` (datagram payload <-> ROS message fields, pure), ``diagnostics``
(RT timing -> RtStatus and DiagnosticStatus, pure), ``ports`` (one reader thread per XDDP port).
"""
