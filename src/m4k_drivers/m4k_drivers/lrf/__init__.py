"""Hokuyo URG-04LX-UG01 laser range finder: SCIP 2.0 protocol, serial driver, simulator, handler.

Modules: ``scip`` (pure protocol), ``urg`` (pyserial driver), ``sim`` (SCIP 2.0 device on a pseudo
terminal), ``handler`` (lifecycle adapter for the driver host, ``make_lrf``; it registers the
backends and the registry imports it, so importing the pure ``scip`` loads no pyserial).
"""
