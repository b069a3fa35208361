"""The kernel's userspace ABI for spidev, i2c-dev and GPIO v2, and a stand-in behind it.

* :mod:`m4k_drivers.abi.uapi` -- the structures and ioctl numbers, from the uapi headers;
* :mod:`m4k_drivers.abi.kernel` -- :class:`~m4k_drivers.abi.kernel.KernelStandIn`, which
  takes the place of the kernel at the ``open``/``ioctl``/``read``/``close`` boundary the
  real backends (python-periphery, smbus2) call through, decodes the real structures from
  the real bytes, and hands the transfers to device models;
* :mod:`m4k_drivers.abi.devices` -- those models, from the parts' datasheets: MCP4911,
  AS5045, myAHRS+ registers, US-100 echo edges, the enable monostable.

Why a stand-in and not the kernel's own mocks: this machine's kernel has no gpio-sim,
i2c-stub, spidev loopback or uleds (no modules, no configfs) and FUSE cannot carry ioctls that
point into user memory (SPI_IOC_MESSAGE, I2C_RDWR); see docs/real-robot.md, "Kernel ABI
stand-in".
"""
