#!/usr/bin/env bash
# Cut one sync of the recorder's writer at every byte of every write, and open every cut as
# Lichtblick does (tear.mjs). Needs `npm ci` here first, and the workspace built (make build).
#   tools/mcap-check/tear.sh            the writer in this checkout
#   tools/mcap-check/tear.sh REV        the writer of git revision REV (for comparison; report only)
set -euo pipefail
here=$(cd "$(dirname "$0")" && pwd)
[[ -d $here/node_modules/@mcap/core ]] || { echo "tear.sh: run 'npm ci' in $here first (node 20, npm)" >&2; exit 2; }
cd "$here/../.."
source tools/env.sh
out=$(mktemp -d /tmp/m4k-tears.XXXXXX)
trap 'rm -rf "$out"' EXIT
if [[ -n ${1:-} ]]; then
  git show "$1:src/m4k_bridge/m4k_bridge/bag/writer.py" > "$out/writer_at_rev.py"
fi
python - "$out" <<'PY'
import importlib.util, os, sys
sys.path.insert(0, 'src/m4k_bridge/test')
import bag_tears
out = sys.argv[1]
mod = None
path = os.path.join(out, 'writer_at_rev.py')
if os.path.exists(path):
    spec = importlib.util.spec_from_file_location('writer_at_rev', path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules['writer_at_rev'] = mod
    spec.loader.exec_module(mod)
m = bag_tears.tear_images(os.path.join(out, 'cuts'), mod)
print('writes of the cut sync:', m['ops'])
PY
node "$here/tear.mjs" "$out/cuts" ${1:+--report-only}
