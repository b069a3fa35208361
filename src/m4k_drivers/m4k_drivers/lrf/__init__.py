"""Hokuyo URG-04LX-UG01 laser range finder: SCIP 2.0 protocol, serial driver, simulator, handler.

Modules: ``scip`` (pure protocol), ``urg`` (pyserial driver), ``sim`` (SCIP 2.0 device on a pseudo
terminal), ``handler`` (lifecycle handler around an opener of the port), ``service`` (how the
driver host serves it), ``backends`` (``real`` and ``sim``, registered for kind ``lrf``; the
registry imports it, so importing this package or the pure ``scip`` loads no pyserial).
"""
