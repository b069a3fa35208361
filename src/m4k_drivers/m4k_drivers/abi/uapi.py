"""Linux userspace ABI of spidev, i2c-dev and the GPIO character device (v2), as ctypes.

Written from the uapi headers, not from any user of them:

* ``include/uapi/asm-generic/ioctl.h``: ``_IOC(dir, type, nr, size)`` =
  ``dir << 30 | size << 16 | type << 8 | nr`` with ``_IOC_NONE`` 0, ``_IOC_WRITE`` 1,
  ``_IOC_READ`` 2 and a 14-bit size field (x86, arm and arm64 use the generic layout; alpha,
  mips, powerpc and sparc do not, and the Raspberry Pi is arm/arm64);
* ``include/uapi/linux/spi/spidev.h``: ``struct spi_ioc_transfer`` (32 bytes, the same in 32-
  and 64-bit userspace), ``SPI_IOC_MESSAGE(N)`` = ``_IOW('k', 0, char[N * 32])`` and the
  mode / bits-per-word / max-speed ioctls; ``include/uapi/linux/spi/spi.h`` for the mode bits;
* ``include/uapi/linux/i2c-dev.h`` (``I2C_SLAVE`` 0x0703, ``I2C_FUNCS`` 0x0705, ``I2C_RDWR``
  0x0707, ``I2C_SMBUS`` 0x0720, ``struct i2c_rdwr_ioctl_data``, ``struct i2c_smbus_ioctl_data``)
  and ``include/uapi/linux/i2c.h`` (``struct i2c_msg``, ``I2C_M_RD``, ``union i2c_smbus_data``,
  the SMBus transaction sizes and functionality bits);
* ``include/uapi/linux/gpio.h``: the v2 line request, config, attributes, values and the
  edge event record that ``read()`` returns.

``test/test_abi_uapi.py`` compiles a C program against this machine's headers and compares
every size, offset and ioctl number here with what the compiler says.
"""

from __future__ import annotations

import ctypes

__all__ = [
    'GPIO_V2_GET_LINE_IOCTL', 'GPIO_V2_LINE_GET_VALUES_IOCTL', 'GPIO_V2_LINE_SET_CONFIG_IOCTL',
    'GPIO_V2_LINE_SET_VALUES_IOCTL', 'GpioV2LineAttribute', 'GpioV2LineConfig',
    'GpioV2LineConfigAttribute', 'GpioV2LineEvent', 'GpioV2LineRequest', 'GpioV2LineValues',
    'I2cMsg', 'I2cRdwrIoctlData', 'I2cSmbusData', 'I2cSmbusIoctlData', 'SpiIocTransfer',
    'ioc', 'ioc_dir', 'ioc_nr', 'ioc_size', 'ioc_type', 'spi_ioc_message',
]

# -- asm-generic/ioctl.h ------------------------------------------------------------------------
IOC_NRBITS, IOC_TYPEBITS, IOC_SIZEBITS, IOC_DIRBITS = 8, 8, 14, 2
IOC_NRSHIFT = 0
IOC_TYPESHIFT = IOC_NRSHIFT + IOC_NRBITS
IOC_SIZESHIFT = IOC_TYPESHIFT + IOC_TYPEBITS
IOC_DIRSHIFT = IOC_SIZESHIFT + IOC_SIZEBITS
IOC_NONE, IOC_WRITE, IOC_READ = 0, 1, 2


def ioc(direction: int, type_: int, nr: int, size: int) -> int:
    """Return ``_IOC(dir, type, nr, size)``."""
    if not 0 <= size < 1 << IOC_SIZEBITS:
        raise ValueError(f'ioctl size {size!r} does not fit {IOC_SIZEBITS} bits')
    return (direction << IOC_DIRSHIFT | size << IOC_SIZESHIFT | type_ << IOC_TYPESHIFT
            | nr << IOC_NRSHIFT)


def _iow(type_: int, nr: int, size: int) -> int:
    return ioc(IOC_WRITE, type_, nr, size)


def _ior(type_: int, nr: int, size: int) -> int:
    return ioc(IOC_READ, type_, nr, size)


def _iowr(type_: int, nr: int, size: int) -> int:
    return ioc(IOC_READ | IOC_WRITE, type_, nr, size)


def ioc_dir(request: int) -> int:
    """Return the direction field of an ioctl number."""
    return (request >> IOC_DIRSHIFT) & ((1 << IOC_DIRBITS) - 1)


def ioc_type(request: int) -> int:
    """Return the type ('magic') field of an ioctl number."""
    return (request >> IOC_TYPESHIFT) & ((1 << IOC_TYPEBITS) - 1)


def ioc_nr(request: int) -> int:
    """Return the number field of an ioctl number."""
    return (request >> IOC_NRSHIFT) & ((1 << IOC_NRBITS) - 1)


def ioc_size(request: int) -> int:
    """Return the size field of an ioctl number."""
    return (request >> IOC_SIZESHIFT) & ((1 << IOC_SIZEBITS) - 1)


# -- linux/spi/spi.h + spidev.h ----------------------------------------------------------------
SPI_CPHA = 0x01
SPI_CPOL = 0x02
SPI_MODE_X_MASK = SPI_CPOL | SPI_CPHA
SPI_CS_HIGH = 0x04
SPI_LSB_FIRST = 0x08
SPI_3WIRE = 0x10
SPI_LOOP = 0x20
SPI_NO_CS = 0x40
SPI_READY = 0x80
SPI_IOC_MAGIC = ord('k')


class SpiIocTransfer(ctypes.Structure):
    """``struct spi_ioc_transfer``: one segment of a full-duplex SPI message."""

    _fields_ = [
        ('tx_buf', ctypes.c_uint64),          # user address of the bytes to send (0: zeros)
        ('rx_buf', ctypes.c_uint64),          # user address for the bytes received (0: drop)
        ('len', ctypes.c_uint32),
        ('speed_hz', ctypes.c_uint32),        # 0: the device's max_speed_hz
        ('delay_usecs', ctypes.c_uint16),     # after this transfer, before cs_change
        ('bits_per_word', ctypes.c_uint8),    # 0: the device's bits_per_word
        ('cs_change', ctypes.c_uint8),        # 1: deselect the device before the next one
        ('tx_nbits', ctypes.c_uint8),
        ('rx_nbits', ctypes.c_uint8),
        ('word_delay_usecs', ctypes.c_uint8),
        ('pad', ctypes.c_uint8),
    ]


SPI_TRANSFER_SIZE = ctypes.sizeof(SpiIocTransfer)


def spi_msgsize(n: int) -> int:
    """Return ``SPI_MSGSIZE(N)`` (0 when N transfers do not fit the size field)."""
    size = n * SPI_TRANSFER_SIZE
    return size if size < 1 << IOC_SIZEBITS else 0


def spi_ioc_message(n: int) -> int:
    """Return ``SPI_IOC_MESSAGE(N)``."""
    return _iow(SPI_IOC_MAGIC, 0, spi_msgsize(n))


SPI_IOC_RD_MODE = _ior(SPI_IOC_MAGIC, 1, 1)
SPI_IOC_WR_MODE = _iow(SPI_IOC_MAGIC, 1, 1)
SPI_IOC_RD_LSB_FIRST = _ior(SPI_IOC_MAGIC, 2, 1)
SPI_IOC_WR_LSB_FIRST = _iow(SPI_IOC_MAGIC, 2, 1)
SPI_IOC_RD_BITS_PER_WORD = _ior(SPI_IOC_MAGIC, 3, 1)
SPI_IOC_WR_BITS_PER_WORD = _iow(SPI_IOC_MAGIC, 3, 1)
SPI_IOC_RD_MAX_SPEED_HZ = _ior(SPI_IOC_MAGIC, 4, 4)
SPI_IOC_WR_MAX_SPEED_HZ = _iow(SPI_IOC_MAGIC, 4, 4)
SPI_IOC_RD_MODE32 = _ior(SPI_IOC_MAGIC, 5, 4)
SPI_IOC_WR_MODE32 = _iow(SPI_IOC_MAGIC, 5, 4)

# -- linux/i2c-dev.h + i2c.h -------------------------------------------------------------------
I2C_RETRIES = 0x0701
I2C_TIMEOUT = 0x0702
I2C_SLAVE = 0x0703
I2C_TENBIT = 0x0704
I2C_FUNCS = 0x0705
I2C_SLAVE_FORCE = 0x0706
I2C_RDWR = 0x0707
I2C_PEC = 0x0708
I2C_SMBUS = 0x0720
I2C_RDWR_IOCTL_MAX_MSGS = 42
I2C_M_RD = 0x0001
I2C_M_TEN = 0x0010
I2C_M_RECV_LEN = 0x0400
I2C_SMBUS_BLOCK_MAX = 32
I2C_SMBUS_READ, I2C_SMBUS_WRITE = 1, 0
I2C_SMBUS_QUICK = 0
I2C_SMBUS_BYTE = 1
I2C_SMBUS_BYTE_DATA = 2
I2C_SMBUS_WORD_DATA = 3
I2C_SMBUS_PROC_CALL = 4
I2C_SMBUS_BLOCK_DATA = 5
I2C_SMBUS_I2C_BLOCK_BROKEN = 6
I2C_SMBUS_BLOCK_PROC_CALL = 7
I2C_SMBUS_I2C_BLOCK_DATA = 8
I2C_FUNC_I2C = 0x00000001
I2C_FUNC_SMBUS_READ_BYTE_DATA = 0x00080000
I2C_FUNC_SMBUS_WRITE_BYTE_DATA = 0x00100000
I2C_FUNC_SMBUS_READ_I2C_BLOCK = 0x04000000
I2C_FUNC_SMBUS_WRITE_I2C_BLOCK = 0x08000000


class I2cMsg(ctypes.Structure):
    """``struct i2c_msg``: one segment of a combined transaction (a START each)."""

    _fields_ = [
        ('addr', ctypes.c_uint16),
        ('flags', ctypes.c_uint16),
        ('len', ctypes.c_uint16),
        ('buf', ctypes.c_void_p),             # __u8 *buf
    ]


class I2cRdwrIoctlData(ctypes.Structure):
    """``struct i2c_rdwr_ioctl_data``: the I2C_RDWR argument."""

    _fields_ = [
        ('msgs', ctypes.c_void_p),            # struct i2c_msg *msgs
        ('nmsgs', ctypes.c_uint32),
    ]


class I2cSmbusData(ctypes.Union):
    """``union i2c_smbus_data``: block[0] is the length, one spare byte for user space."""

    _fields_ = [
        ('byte', ctypes.c_uint8),
        ('word', ctypes.c_uint16),
        ('block', ctypes.c_uint8 * (I2C_SMBUS_BLOCK_MAX + 2)),
    ]


class I2cSmbusIoctlData(ctypes.Structure):
    """``struct i2c_smbus_ioctl_data``: the I2C_SMBUS argument."""

    _fields_ = [
        ('read_write', ctypes.c_uint8),
        ('command', ctypes.c_uint8),
        ('size', ctypes.c_uint32),
        ('data', ctypes.c_void_p),            # union i2c_smbus_data *data
    ]


# -- linux/gpio.h (v2) -------------------------------------------------------------------------
GPIO_MAX_NAME_SIZE = 32
GPIO_V2_LINES_MAX = 64
GPIO_V2_LINE_NUM_ATTRS_MAX = 10
GPIO_V2_LINE_FLAG_USED = 1 << 0
GPIO_V2_LINE_FLAG_ACTIVE_LOW = 1 << 1
GPIO_V2_LINE_FLAG_INPUT = 1 << 2
GPIO_V2_LINE_FLAG_OUTPUT = 1 << 3
GPIO_V2_LINE_FLAG_EDGE_RISING = 1 << 4
GPIO_V2_LINE_FLAG_EDGE_FALLING = 1 << 5
GPIO_V2_LINE_FLAG_OPEN_DRAIN = 1 << 6
GPIO_V2_LINE_FLAG_OPEN_SOURCE = 1 << 7
GPIO_V2_LINE_FLAG_BIAS_PULL_UP = 1 << 8
GPIO_V2_LINE_FLAG_BIAS_PULL_DOWN = 1 << 9
GPIO_V2_LINE_FLAG_BIAS_DISABLED = 1 << 10
GPIO_V2_LINE_FLAG_EVENT_CLOCK_REALTIME = 1 << 11
GPIO_V2_LINE_FLAG_EVENT_CLOCK_HTE = 1 << 12
GPIO_V2_LINE_ATTR_ID_FLAGS = 1
GPIO_V2_LINE_ATTR_ID_OUTPUT_VALUES = 2
GPIO_V2_LINE_ATTR_ID_DEBOUNCE = 3
GPIO_V2_LINE_EVENT_RISING_EDGE = 1
GPIO_V2_LINE_EVENT_FALLING_EDGE = 2


class GpioV2LineValues(ctypes.Structure):
    """``struct gpio_v2_line_values``: bit i of ``bits`` is line i of the request."""

    _fields_ = [('bits', ctypes.c_uint64), ('mask', ctypes.c_uint64)]


class _AttrValue(ctypes.Union):
    _fields_ = [('flags', ctypes.c_uint64), ('values', ctypes.c_uint64),
                ('debounce_period_us', ctypes.c_uint32)]


class GpioV2LineAttribute(ctypes.Structure):
    """``struct gpio_v2_line_attribute``: id + (flags | values | debounce) union."""

    _anonymous_ = ('u',)
    _fields_ = [('id', ctypes.c_uint32), ('padding', ctypes.c_uint32), ('u', _AttrValue)]


class GpioV2LineConfigAttribute(ctypes.Structure):
    """``struct gpio_v2_line_config_attribute``: an attribute for the lines in ``mask``."""

    _fields_ = [('attr', GpioV2LineAttribute), ('mask', ctypes.c_uint64)]


class GpioV2LineConfig(ctypes.Structure):
    """``struct gpio_v2_line_config``: default flags plus up to 10 per-line attributes."""

    _fields_ = [
        ('flags', ctypes.c_uint64),
        ('num_attrs', ctypes.c_uint32),
        ('padding', ctypes.c_uint32 * 5),
        ('attrs', GpioV2LineConfigAttribute * GPIO_V2_LINE_NUM_ATTRS_MAX),
    ]


class GpioV2LineRequest(ctypes.Structure):
    """``struct gpio_v2_line_request``: the GPIO_V2_GET_LINE_IOCTL argument (``fd`` out)."""

    _fields_ = [
        ('offsets', ctypes.c_uint32 * GPIO_V2_LINES_MAX),
        ('consumer', ctypes.c_char * GPIO_MAX_NAME_SIZE),
        ('config', GpioV2LineConfig),
        ('num_lines', ctypes.c_uint32),
        ('event_buffer_size', ctypes.c_uint32),
        ('padding', ctypes.c_uint32 * 5),
        ('fd', ctypes.c_int32),
    ]


class GpioV2LineEvent(ctypes.Structure):
    """``struct gpio_v2_line_event``: one record read() from a line request fd."""

    _fields_ = [
        ('timestamp_ns', ctypes.c_uint64),
        ('id', ctypes.c_uint32),
        ('offset', ctypes.c_uint32),
        ('seqno', ctypes.c_uint32),
        ('line_seqno', ctypes.c_uint32),
        ('padding', ctypes.c_uint32 * 6),
    ]


GPIO_V2_GET_LINE_IOCTL = _iowr(0xB4, 0x07, ctypes.sizeof(GpioV2LineRequest))
GPIO_V2_LINE_SET_CONFIG_IOCTL = _iowr(0xB4, 0x0D, ctypes.sizeof(GpioV2LineConfig))
GPIO_V2_LINE_GET_VALUES_IOCTL = _iowr(0xB4, 0x0E, ctypes.sizeof(GpioV2LineValues))
GPIO_V2_LINE_SET_VALUES_IOCTL = _iowr(0xB4, 0x0F, ctypes.sizeof(GpioV2LineValues))

# Every name the test compares with the C compiler: (python value, C expression).
CHECKS: dict[str, tuple[int, str]] = {
    'sizeof spi_ioc_transfer': (SPI_TRANSFER_SIZE, 'sizeof(struct spi_ioc_transfer)'),
    'SPI_IOC_MESSAGE(1)': (spi_ioc_message(1), 'SPI_IOC_MESSAGE(1)'),
    'SPI_IOC_MESSAGE(2)': (spi_ioc_message(2), 'SPI_IOC_MESSAGE(2)'),
    'SPI_IOC_RD_MODE': (SPI_IOC_RD_MODE, 'SPI_IOC_RD_MODE'),
    'SPI_IOC_WR_MODE': (SPI_IOC_WR_MODE, 'SPI_IOC_WR_MODE'),
    'SPI_IOC_RD_BITS_PER_WORD': (SPI_IOC_RD_BITS_PER_WORD, 'SPI_IOC_RD_BITS_PER_WORD'),
    'SPI_IOC_WR_BITS_PER_WORD': (SPI_IOC_WR_BITS_PER_WORD, 'SPI_IOC_WR_BITS_PER_WORD'),
    'SPI_IOC_RD_MAX_SPEED_HZ': (SPI_IOC_RD_MAX_SPEED_HZ, 'SPI_IOC_RD_MAX_SPEED_HZ'),
    'SPI_IOC_WR_MAX_SPEED_HZ': (SPI_IOC_WR_MAX_SPEED_HZ, 'SPI_IOC_WR_MAX_SPEED_HZ'),
    'SPI_IOC_RD_MODE32': (SPI_IOC_RD_MODE32, 'SPI_IOC_RD_MODE32'),
    'SPI_IOC_WR_MODE32': (SPI_IOC_WR_MODE32, 'SPI_IOC_WR_MODE32'),
    'offsetof spi_ioc_transfer.len': (SpiIocTransfer.len.offset,
                                      'offsetof(struct spi_ioc_transfer, len)'),
    'offsetof spi_ioc_transfer.delay_usecs': (
        SpiIocTransfer.delay_usecs.offset, 'offsetof(struct spi_ioc_transfer, delay_usecs)'),
    'offsetof spi_ioc_transfer.cs_change': (
        SpiIocTransfer.cs_change.offset, 'offsetof(struct spi_ioc_transfer, cs_change)'),
    'I2C_SLAVE': (I2C_SLAVE, 'I2C_SLAVE'), 'I2C_FUNCS': (I2C_FUNCS, 'I2C_FUNCS'),
    'I2C_RDWR': (I2C_RDWR, 'I2C_RDWR'), 'I2C_SMBUS': (I2C_SMBUS, 'I2C_SMBUS'),
    'I2C_M_RD': (I2C_M_RD, 'I2C_M_RD'),
    'I2C_SMBUS_BYTE_DATA': (I2C_SMBUS_BYTE_DATA, 'I2C_SMBUS_BYTE_DATA'),
    'I2C_SMBUS_I2C_BLOCK_DATA': (I2C_SMBUS_I2C_BLOCK_DATA, 'I2C_SMBUS_I2C_BLOCK_DATA'),
    'I2C_FUNC_I2C': (I2C_FUNC_I2C, 'I2C_FUNC_I2C'),
    'sizeof i2c_msg': (ctypes.sizeof(I2cMsg), 'sizeof(struct i2c_msg)'),
    'offsetof i2c_msg.len': (I2cMsg.len.offset, 'offsetof(struct i2c_msg, len)'),
    'offsetof i2c_msg.buf': (I2cMsg.buf.offset, 'offsetof(struct i2c_msg, buf)'),
    'sizeof i2c_rdwr_ioctl_data': (ctypes.sizeof(I2cRdwrIoctlData),
                                   'sizeof(struct i2c_rdwr_ioctl_data)'),
    'offsetof i2c_rdwr_ioctl_data.nmsgs': (
        I2cRdwrIoctlData.nmsgs.offset, 'offsetof(struct i2c_rdwr_ioctl_data, nmsgs)'),
    'sizeof i2c_smbus_ioctl_data': (ctypes.sizeof(I2cSmbusIoctlData),
                                    'sizeof(struct i2c_smbus_ioctl_data)'),
    'offsetof i2c_smbus_ioctl_data.size': (
        I2cSmbusIoctlData.size.offset, 'offsetof(struct i2c_smbus_ioctl_data, size)'),
    'offsetof i2c_smbus_ioctl_data.data': (
        I2cSmbusIoctlData.data.offset, 'offsetof(struct i2c_smbus_ioctl_data, data)'),
    'sizeof i2c_smbus_data': (ctypes.sizeof(I2cSmbusData), 'sizeof(union i2c_smbus_data)'),
    'sizeof gpio_v2_line_values': (ctypes.sizeof(GpioV2LineValues),
                                   'sizeof(struct gpio_v2_line_values)'),
    'sizeof gpio_v2_line_attribute': (ctypes.sizeof(GpioV2LineAttribute),
                                      'sizeof(struct gpio_v2_line_attribute)'),
    'sizeof gpio_v2_line_config_attribute': (
        ctypes.sizeof(GpioV2LineConfigAttribute), 'sizeof(struct gpio_v2_line_config_attribute)'),
    'sizeof gpio_v2_line_config': (ctypes.sizeof(GpioV2LineConfig),
                                   'sizeof(struct gpio_v2_line_config)'),
    'offsetof gpio_v2_line_config.attrs': (
        GpioV2LineConfig.attrs.offset, 'offsetof(struct gpio_v2_line_config, attrs)'),
    'sizeof gpio_v2_line_request': (ctypes.sizeof(GpioV2LineRequest),
                                    'sizeof(struct gpio_v2_line_request)'),
    'offsetof gpio_v2_line_request.config': (
        GpioV2LineRequest.config.offset, 'offsetof(struct gpio_v2_line_request, config)'),
    'offsetof gpio_v2_line_request.num_lines': (
        GpioV2LineRequest.num_lines.offset, 'offsetof(struct gpio_v2_line_request, num_lines)'),
    'offsetof gpio_v2_line_request.fd': (
        GpioV2LineRequest.fd.offset, 'offsetof(struct gpio_v2_line_request, fd)'),
    'sizeof gpio_v2_line_event': (ctypes.sizeof(GpioV2LineEvent),
                                  'sizeof(struct gpio_v2_line_event)'),
    'offsetof gpio_v2_line_event.seqno': (
        GpioV2LineEvent.seqno.offset, 'offsetof(struct gpio_v2_line_event, seqno)'),
    'GPIO_V2_GET_LINE_IOCTL': (GPIO_V2_GET_LINE_IOCTL, 'GPIO_V2_GET_LINE_IOCTL'),
    'GPIO_V2_LINE_SET_CONFIG_IOCTL': (GPIO_V2_LINE_SET_CONFIG_IOCTL,
                                      'GPIO_V2_LINE_SET_CONFIG_IOCTL'),
    'GPIO_V2_LINE_GET_VALUES_IOCTL': (GPIO_V2_LINE_GET_VALUES_IOCTL,
                                      'GPIO_V2_LINE_GET_VALUES_IOCTL'),
    'GPIO_V2_LINE_SET_VALUES_IOCTL': (GPIO_V2_LINE_SET_VALUES_IOCTL,
                                      'GPIO_V2_LINE_SET_VALUES_IOCTL'),
    'GPIO_V2_LINE_FLAG_EVENT_CLOCK_REALTIME': (GPIO_V2_LINE_FLAG_EVENT_CLOCK_REALTIME,
                                               'GPIO_V2_LINE_FLAG_EVENT_CLOCK_REALTIME'),
    'GPIO_V2_LINE_FLAG_EDGE_FALLING': (GPIO_V2_LINE_FLAG_EDGE_FALLING,
                                       'GPIO_V2_LINE_FLAG_EDGE_FALLING'),
    'GPIO_V2_LINE_ATTR_ID_OUTPUT_VALUES': (GPIO_V2_LINE_ATTR_ID_OUTPUT_VALUES,
                                           'GPIO_V2_LINE_ATTR_ID_OUTPUT_VALUES'),
}
