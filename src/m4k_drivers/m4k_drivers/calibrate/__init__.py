"""Robot identification for bring-up: ``calibrate`` (docs/real-robot.md, "Calibration").

:mod:`~m4k_drivers.calibrate.fit` is the arithmetic (pure), :mod:`~m4k_drivers.calibrate.runs`
the bounded motor runs through the motor handler, :mod:`~m4k_drivers.calibrate.cli` the guided
console tool that writes the config overlay.
"""
