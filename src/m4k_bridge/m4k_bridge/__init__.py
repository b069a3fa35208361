"""The m4k ROS 2 bridge, above m4k_rt: the only rclpy code of the stack (:mod:`m4k_bridge.node`).

Modules: ``node`` (the ``m4k_bridge`` node and ``main``), ``params`` (parameter table and
pure validation), ``convert`` (datagram payload <-> ROS message fields, pure), ``diagnostics``
(RT timing -> RtStatus and DiagnosticStatus, pure), ``ports`` (one reader thread per XDDP port).
"""
