"""Hokuyo URG-04LX-UG01 laser range finder: SCIP 2.0 protocol, serial driver, simulator, handler.

Modules: ``scip`` (pure protocol), ``urg`` (pyserial driver), ``sim`` (SCIP 2.0 device on a pseudo
terminal), ``handler`` (lifecycle adapter for the driver host, ``make_lrf``).
"""

from m4k_drivers.lrf import handler as _handler  # noqa: F401  (registers backends 'real', 'sim')
