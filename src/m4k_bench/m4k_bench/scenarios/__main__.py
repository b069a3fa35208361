"""python -m m4k_bench.scenarios: the suite (see the package docstring)."""

import sys

from m4k_bench.scenarios import main

if __name__ == '__main__':
    sys.exit(main())
