"""The shared m4k fixtures, on their own package's tests too."""

from m4k_testing import *  # noqa: F401,F403
