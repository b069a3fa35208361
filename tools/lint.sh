#!/usr/bin/env bash
# The one lint command (`make lint`, tools/run-tests.sh): ruff (99 columns, single quotes,
# pep257), then mypy (mypy.ini: strict on the RT core and the pure protocol modules).
# Expects the workspace environment (source tools/env.sh).
set -uo pipefail
cd "$(dirname "$0")/.."
rc=0
ruff check src test tools || rc=1
mypy --config-file mypy.ini || rc=1
exit $rc
