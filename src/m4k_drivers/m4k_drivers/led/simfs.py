"""The LED strip as sysfs files: a multicolor LED-class device and a PWM chip, polled.

``sim_robot`` lays out, under ``<runtime_dir>/sim-sysfs``, what the kernel shows under ``/sys``:

* ``class/leds/<name>/``: ``max_brightness``, ``brightness``, ``multi_index`` (the channel order,
  e.g. ``green red blue`` -- drivers must follow it), ``multi_intensity``;
* ``class/pwm/pwmchip<N>/``: ``npwm``, ``export``, ``unexport``; writing a channel number to
  ``export`` makes ``pwm<K>/`` appear with ``period``, ``duty_cycle``, ``enable``, ``polarity``
  (``export``/``unexport`` are FIFOs, so every write is seen, as the kernel sees each one).

The real LED backends write these files unchanged (their ``sysfs_root`` option), and
:meth:`SysfsLeds.poll` interprets them as the kernel does (Documentation/leds/leds-class-
multicolor.rst, Documentation/ABI/testing/sysfs-class-pwm): a multicolor channel shows
``brightness * intensity / max_brightness``; a PWM channel ``duty_cycle / period`` when enabled
(``1 -`` that when ``inversed``), off when disabled.  What the kernel would refuse with EINVAL
(a ``multi_intensity`` without one value per ``multi_index`` entry, values above
``max_brightness``, a ``duty_cycle`` longer than the ``period``) cannot be refused by a plain
file: it is counted in ``errors`` with the reason in ``last_error``, and the output keeps its
previous level, as after a rejected write. A rejected write is counted once, like the one EINVAL
the kernel returns for it: polls that find the same files unchanged (same contents, same
modification stamps) do not count it again; a new write, even of the same bad value, does.

Plain files cannot fail a write, so the PWM attributes are also reachable the way the kernel
applies them: :meth:`SysfsLeds.write_attr` (sim_robot serves it on the sim-bus, op
``SYSFS_WRITE``; the ``sim`` LED backend writes PWM attributes through it) parses one write,
applies it to the channel's state like ``drivers/pwm/sysfs.c`` + ``pwm_apply_state()`` of the
strict kernels (Raspberry Pi 5.10..6.6; relaxed only by a mid-2024 patch) and raises
``OSError`` as they do: EINVAL for any apply while ``period`` is 0 -- a fresh export has period
0, so ``enable``, ``duty_cycle`` and ``polarity`` are all refused until a period is written --
and for ``duty_cycle > period``; EBUSY for a polarity change while enabled; EINVAL for an
unparsable value, EBUSY for exporting an exported channel.  Polling the files also counts an
enabled channel or a duty cycle above 0 with period 0 as the EINVAL it would have been.
"""

from __future__ import annotations

import errno
import os
import shutil
import threading
import time
from typing import Any, Callable

__all__ = ['COLORS', 'SysfsLeds']

COLORS = ('red', 'green', 'blue')


def _read(path: str) -> str:
    try:
        with open(path, encoding='ascii') as fh:
            return fh.read().strip()
    except (OSError, UnicodeDecodeError):
        return ''


def _write(path: str, text: str) -> None:
    with open(path, 'w', encoding='ascii') as fh:
        fh.write(text + '\n')


class SysfsLeds:
    """The simulated strip behind LED-class and PWM sysfs files (``section``: devices.led)."""

    def __init__(self, root: str, section: dict[str, Any],
                 clock: Callable[[], int] = time.monotonic_ns) -> None:
        self.root = root
        self.clock = clock
        self.max_brightness = 255
        self.order = tuple(section.get('multi_index') or COLORS)
        if sorted(self.order) != sorted(COLORS):
            raise ValueError(f'devices.led.multi_index: expected the three colours '
                             f'{COLORS!r} in some order, got {list(self.order)!r}')
        self.led_dir = os.path.join(root, 'class', 'leds', str(section.get('name', 'rgb:status')))
        self.chip = int(section.get('chip', 0))
        self.channels = tuple(int(c) for c in section.get('channels', (0, 1, 2)))
        self.chip_dir = os.path.join(root, 'class', 'pwm', f'pwmchip{self.chip}')
        self.interface = section.get('interface', 'led_class')
        self.levels = (0.0, 0.0, 0.0)          # r, g, b output in [0, 1]
        self.history: list[tuple[int, tuple[float, float, float]]] = []
        self.errors = 0
        self.last_error = ''
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._fifos: dict[str, tuple[int, int]] = {}     # name -> (read fd, keep-open write fd)
        self._rejected: dict[str, tuple[Any, ...]] = {}  # site -> the files it was counted for

    # -- the tree -------------------------------------------------------------------------
    def start(self, period_s: float = 0.02) -> SysfsLeds:
        """Create the files and poll them every ``period_s`` from a thread."""
        os.makedirs(self.led_dir, exist_ok=True)
        # Only who may use the runtime directory may reach the files (its mode: 0700 / 0770).
        os.chmod(self.root, os.stat(os.path.dirname(self.root)).st_mode & 0o770)
        _write(os.path.join(self.led_dir, 'max_brightness'), str(self.max_brightness))
        _write(os.path.join(self.led_dir, 'brightness'), '0')
        _write(os.path.join(self.led_dir, 'multi_index'), ' '.join(self.order))
        _write(os.path.join(self.led_dir, 'multi_intensity'), '0 0 0')
        os.makedirs(self.chip_dir, exist_ok=True)
        _write(os.path.join(self.chip_dir, 'npwm'), str(max(self.channels) + 1))
        for name in ('export', 'unexport'):
            path = os.path.join(self.chip_dir, name)
            if not os.path.exists(path):
                os.mkfifo(path, 0o600)
            rfd = os.open(path, os.O_RDONLY | os.O_NONBLOCK | os.O_CLOEXEC)
            # Our own writer keeps the FIFO open: writers never block, readers never see EOF.
            self._fifos[name] = (rfd, os.open(path, os.O_WRONLY | os.O_CLOEXEC))
        self._thread = threading.Thread(target=self._run, args=(period_s,), name='sim-leds',
                                        daemon=True)
        self._thread.start()
        return self

    def close(self) -> None:
        """Stop polling and remove the tree."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(2.0)
        for fds in self._fifos.values():
            for fd in fds:
                os.close(fd)
        self._fifos.clear()
        shutil.rmtree(self.root, ignore_errors=True)

    def _run(self, period_s: float) -> None:
        while not self._stop.wait(period_s):
            self.poll()

    # -- the kernel's side ----------------------------------------------------------------
    def _error(self, why: str) -> None:
        self.errors += 1
        self.last_error = why

    def _reject(self, site: str, paths: list[str], texts: list[str], why: str) -> None:
        """Count a rejected write at ``site`` once: not again while its files are unchanged."""
        stamps: list[tuple[int, int, int] | None] = []
        for path in paths:
            try:
                st = os.stat(path)
                stamps.append((st.st_mtime_ns, st.st_ctime_ns, st.st_size))
            except OSError:
                stamps.append(None)
        # The stamps must be those of the contents judged: a writer's open('w') may have
        # truncated (or rewritten) a file since ``texts`` were read -- then the stamps are
        # the next write's, and counting them would count this write again when that one
        # settles. Not counted now: a later poll judges the settled files.
        if [_read(path) for path in paths] != list(texts):
            return
        sig = (tuple(texts), tuple(stamps))
        if self._rejected.get(site) == sig:
            return
        self._rejected[site] = sig
        self._error(why)

    def _exports(self) -> None:
        for name, make in (('export', True), ('unexport', False)):
            if name not in self._fifos:
                continue
            try:
                data = os.read(self._fifos[name][0], 4096)
            except BlockingIOError:
                continue
            for text in data.decode('ascii', errors='replace').split():
                self._export(name, make, text)

    def _export(self, name: str, make: bool, text: str) -> None:
        try:
            ch = int(text)
        except ValueError:
            self._error(f'{name}: not a channel number: {text!r}')
            return
        if not 0 <= ch <= max(self.channels):
            self._error(f'{name}: no channel {ch}')
            return
        d = os.path.join(self.chip_dir, f'pwm{ch}')
        if make and not os.path.isdir(d):
            # The channel appears whole (built aside, renamed in): a driver waiting for its
            # files must never write one that the "kernel" then initialises over.
            tmp = d + '.new'
            os.makedirs(tmp, exist_ok=True)
            for attr, value in (('period', '0'), ('duty_cycle', '0'), ('enable', '0'),
                                ('polarity', 'normal')):
                _write(os.path.join(tmp, attr), value)
            os.rename(tmp, d)
        elif not make:
            shutil.rmtree(d, ignore_errors=True)

    def write_attr(self, path: str, text: str) -> None:
        """Apply one write to a PWM file under this tree as a strict kernel does (OSError)."""
        rel = os.path.relpath(os.path.realpath(path), os.path.realpath(self.chip_dir))
        value = text.strip()
        parts = rel.split(os.sep)
        with self._lock:
            if rel in ('export', 'unexport'):
                try:
                    ch = int(value)
                except ValueError:
                    raise OSError(errno.EINVAL, os.strerror(errno.EINVAL), path) from None
                d = os.path.join(self.chip_dir, f'pwm{ch}')
                if not 0 <= ch <= max(self.channels) or (rel == 'unexport'
                                                         and not os.path.isdir(d)):
                    raise OSError(errno.EINVAL, os.strerror(errno.EINVAL), path)
                if rel == 'export' and os.path.isdir(d):
                    raise OSError(errno.EBUSY, os.strerror(errno.EBUSY), path)
                self._export(rel, rel == 'export', value)
                return
            attrs = ('period', 'duty_cycle', 'enable', 'polarity')
            if len(parts) != 2 or not parts[0].startswith('pwm') or parts[1] not in attrs:
                raise OSError(errno.EACCES, os.strerror(errno.EACCES), path)
            d = os.path.join(self.chip_dir, parts[0])
            if not os.path.isdir(d):
                raise OSError(errno.ENOENT, os.strerror(errno.ENOENT), path)
            st = {a: _read(os.path.join(d, a)) for a in attrs}
            self._apply(st, parts[1], value, path)
            _write(os.path.join(d, parts[1]), value)

    @staticmethod
    def _apply(st: dict[str, str], attr: str, value: str, path: str) -> None:
        """Raise the OSError ``pwm_apply_state`` (strict kernels) gives this write, if any."""
        def refuse(err: int) -> None:
            raise OSError(err, os.strerror(err), path)
        new = dict(st, **{attr: value})
        if attr == 'polarity':
            if value not in ('normal', 'inversed'):
                refuse(errno.EINVAL)
            if st['enable'] == '1' and value != st['polarity']:
                refuse(errno.EBUSY)
        try:
            period, duty, enable = int(new['period']), int(new['duty_cycle']), int(new['enable'])
        except ValueError:
            refuse(errno.EINVAL)
        if min(period, duty) < 0 or enable not in (0, 1):
            refuse(errno.EINVAL)
        # pwm_apply_state(): "if (!state->period || state->duty_cycle > state->period)".
        if period == 0 or duty > period:
            refuse(errno.EINVAL)

    def _led_class(self) -> tuple[float, float, float] | None:
        paths = [os.path.join(self.led_dir, a) for a in ('brightness', 'multi_intensity')]
        bri_text, multi_text = texts = [_read(path) for path in paths]
        if not bri_text or not multi_text:
            return None      # truncated by open() and not written yet: look again next poll
        try:
            bri = int(bri_text)
            values = [int(v) for v in multi_text.split()]
        except ValueError as exc:
            self._reject('led_class', paths, texts, f'LED class: {exc}')
            return None
        if len(values) != len(self.order):
            self._reject('led_class', paths, texts,
                         f'multi_intensity: {len(values)} values for multi_index '
                         f'{" ".join(self.order)!r}')
            return None
        if not 0 <= bri <= self.max_brightness or any(
                not 0 <= v <= self.max_brightness for v in values):
            self._reject('led_class', paths, texts,
                         f'LED class: value above max_brightness {self.max_brightness}')
            return None
        by_color = dict(zip(self.order, values, strict=True))
        m = float(self.max_brightness)
        return tuple(bri * by_color[c] / m / m for c in COLORS)

    def _pwm(self) -> tuple[float, float, float] | None:
        out = []
        for ch in self.channels:
            d = os.path.join(self.chip_dir, f'pwm{ch}')
            if not os.path.isdir(d):
                out.append(0.0)
                continue
            paths = [os.path.join(d, a) for a in ('period', 'duty_cycle', 'enable', 'polarity')]
            texts = [_read(path) for path in paths]
            if not all(texts):
                return None  # a write in progress (truncated, not written): next poll
            site = f'pwm{ch}'
            try:
                period, duty, enable = (int(t) for t in texts[:3])
            except ValueError as exc:
                self._reject(site, paths, texts, f'pwm{ch}: {exc}')
                return None
            polarity = texts[3]
            if period == 0 and (enable or duty > 0):
                self._reject(site, paths, texts,
                             f'pwm{ch}: enable {enable} duty_cycle {duty} with period 0 (EINVAL)')
                return None
            if duty > period:
                self._reject(site, paths, texts,
                             f'pwm{ch}: duty_cycle {duty} > period {period} (EINVAL)')
                return None
            if polarity not in ('normal', 'inversed'):
                self._reject(site, paths, texts, f'pwm{ch}: polarity {polarity!r}')
                return None
            level = duty / period if enable and period > 0 else 0.0
            if enable and polarity == 'inversed':
                level = 1.0 - level
            out.append(level)
        return tuple(out)  # type: ignore[return-value]

    def poll(self) -> tuple[float, float, float]:
        """Read the files as the kernel would apply them; return the r, g, b levels."""
        with self._lock:
            self._exports()
            new = self._pwm() if self.interface == 'pwm' else self._led_class()
            if new is not None and new != self.levels:
                self.levels = new
                self.history.append((self.clock(), new))
                del self.history[:-1000]
            return self.levels

    def shown(self) -> dict[str, Any]:
        """Return the strip's output (levels 0..1) and the error count, for the ground truth."""
        r, g, b = self.levels
        return {'r': r, 'g': g, 'b': b, 'errors': self.errors, 'last_error': self.last_error}
