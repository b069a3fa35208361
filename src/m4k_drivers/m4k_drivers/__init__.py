"""m4k NRT device drivers: handlers (real + simulated backends), the sim world, driver host.

Layout per device (motors, imu, sonar, led, lrf): ``protocol.py`` pure frame/register logic,
``real.py`` / ``sim.py`` transports, ``handler.py`` the thin lifecycle handler; backends are
registered in the package ``__init__`` through :mod:`m4k_drivers.registry`.
"""
