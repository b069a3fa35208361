"""echo_peer: the NRT peer of the echo task bodies (``m4k_rt.tasks.echo``).

One thread per port label writes every datagram it reads straight back, re-linking when the
RT side restarts: the RT machinery exercised without any device (``core_bench``, the tests).
"""

import argparse
import sys
import threading
from typing import Any, Sequence

from m4k_rt import channel, rosargs
from m4k_rt.stopsignals import StopSignals

__all__ = ['EchoPeer', 'main']


class EchoPeer:
    """NRT echo peer: one thread per label, writing back whatever it reads."""

    def __init__(self, labels: Sequence[int | str], runtime_dir: str | None = None) -> None:
        """Prepare (not start) one re-linking endpoint per label."""
        self._links = [channel.NrtLink(lb, runtime_dir, retry_interval=0.05) for lb in labels]
        self._stop = threading.Event()
        self._threads = [threading.Thread(target=self._serve, args=(lk,), daemon=True,
                                          name='echo:{}'.format(lk.port_or_label))
                         for lk in self._links]
        self.echoed = 0

    def start(self) -> 'EchoPeer':
        """Start serving."""
        for t in self._threads:
            t.start()
        return self

    def _serve(self, link: Any) -> None:
        while not self._stop.is_set():
            data = link.read(0.1)
            if data is None:
                if not link.linked:
                    self._stop.wait(0.02)
                continue
            if link.write(data):
                self.echoed += 1

    def stop(self, timeout: float = 2.0) -> None:
        """Stop the threads and close the endpoints."""
        self._stop.set()
        for t in self._threads:
            t.join(timeout)
        for lk in self._links:
            lk.close()

    def __enter__(self) -> 'EchoPeer':
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


def main(argv: Sequence[str] | None = None) -> int:
    """Run an NRT echo peer on the given port labels until SIGINT/SIGTERM."""
    stop = StopSignals().install()  # first: a stop during start-up ends it cleanly, too
    ap = argparse.ArgumentParser(description='NRT echo peer for the echo task bodies.')
    ap.add_argument('labels', nargs='+', help='port labels (or numbers) to serve')
    ap.add_argument('--runtime-dir', default=None)
    args = rosargs.parse_args(ap, argv)
    labels: list[int | str] = [int(x) if x.isdigit() else x for x in args.labels]
    done = stop.event
    peer = EchoPeer(labels, args.runtime_dir).start()
    sys.stderr.write('echo peer: serving {}\n'.format(', '.join(map(str, labels))))
    sys.stderr.flush()
    try:
        while not done.wait(0.5):
            pass
    finally:
        peer.stop()
    sys.stderr.write('echo peer: echoed {} datagrams\n'.format(peer.echoed))
    return 0


if __name__ == '__main__':
    sys.exit(main())
