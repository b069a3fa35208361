"""The ctypes ABI models agree with the C compiler on this machine's uapi headers."""

from __future__ import annotations

import os
import shutil
import subprocess

import pytest

from m4k_drivers.abi import uapi

HEADERS = ('linux/spi/spidev.h', 'linux/i2c.h', 'linux/i2c-dev.h', 'linux/gpio.h')


def _compile_and_run(tmp_path) -> dict[str, int]:
    lines = ['#include <stdio.h>', '#include <stddef.h>']
    lines += [f'#include <{h}>' for h in HEADERS]
    lines.append('int main(void) {')
    for i, (_, (_, expr)) in enumerate(uapi.CHECKS.items()):
        lines.append(f'  printf("{i} %llu\\n", (unsigned long long)({expr}));')
    lines.append('  return 0;\n}')
    src = tmp_path / 'abi.c'
    src.write_text('\n'.join(lines) + '\n')
    exe = tmp_path / 'abi'
    subprocess.run(['gcc', '-Wall', '-o', str(exe), str(src)], check=True,
                   capture_output=True, text=True)
    out = subprocess.run([str(exe)], check=True, capture_output=True, text=True).stdout
    return {int(k): int(v) for k, v in (line.split() for line in out.splitlines())}


def test_every_size_offset_and_ioctl_number_matches_the_headers(tmp_path):
    if shutil.which('gcc') is None:
        pytest.fail('gcc is needed to check the ABI models against the headers')
    missing = [h for h in HEADERS if not os.path.exists(os.path.join('/usr/include', h))]
    assert not missing, f'install linux-libc-dev: missing {missing}'
    got = _compile_and_run(tmp_path)
    names = list(uapi.CHECKS)
    wrong = {names[i]: (uapi.CHECKS[names[i]][0], c) for i, c in got.items()
             if uapi.CHECKS[names[i]][0] != c}
    assert len(got) == len(names)
    assert wrong == {}, f'python value vs C value: {wrong}'


def test_ioc_fields_round_trip():
    req = uapi.GPIO_V2_GET_LINE_IOCTL
    assert uapi.ioc_dir(req) == uapi.IOC_READ | uapi.IOC_WRITE
    assert uapi.ioc_type(req) == 0xB4 and uapi.ioc_nr(req) == 0x07
    assert uapi.ioc_size(req) == 592
    assert uapi.ioc_size(uapi.spi_ioc_message(3)) == 3 * 32
    assert uapi.spi_msgsize(1 << 10) == 0       # does not fit 14 bits: SPI_MSGSIZE says 0
    with pytest.raises(ValueError):
        uapi.ioc(1, 1, 1, 1 << 14)
