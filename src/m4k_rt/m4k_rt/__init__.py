"""m4k real-time core: RT tasks, XDDP emulation, wire protocol, timing statistics."""

__version__ = '0.1.0'
