#!/usr/bin/env bash
# Re-derives the reference figures of crates/skyfuse-core/src/eval.rs's tests (the EVO
# table) with evo itself: writes the fixtures with the ignored test `write_evo_fixtures`,
# then runs `evo_ape tum <case>_ref.tum <case>_est.tum <args>` for every (case, args) of
# that table and prints what evo says, to compare with the table (evo 1.38.1 gave it).
# Needs `pip install evo` (in the venv of tests/run, or any Python).
set -euo pipefail
cd "$(dirname "$0")/../.."
py="${SKYFUSE_PYTHON:-$HOME/.cache/skyfuse-venv/bin/python}"
command -v evo_ape >/dev/null || { echo "evo_ape not found: pip install evo" >&2; exit 1; }
dir=$(mktemp -d)
trap 'rm -rf "$dir"' EXIT
EVO_FIXTURE_DIR="$dir" cargo test -q -p skyfuse-core --lib eval::tests::write_evo_fixtures -- --ignored >/dev/null
# (case, args) pairs of the EVO table.
"$py" - "$dir" <<'PY'
import re, subprocess, sys, json, os, zipfile
d = sys.argv[1]
src = open("crates/skyfuse-core/src/eval.rs").read()
block = src[src.index("const EVO:"):]
block = block[:block.index("];")]
for case, args in re.findall(r'\(\s*"(\w+)",\s*"([^"]*)",', block):
    out = os.path.join(d, f"{case}-{len(args)}.zip")
    cmd = ["evo_ape", "tum", f"{d}/{case}_ref.tum", f"{d}/{case}_est.tum", *args.split(),
           "--save_results", out, "--no_warnings"]
    subprocess.run(cmd, check=True, capture_output=True)
    with zipfile.ZipFile(out) as z:
        stats = json.loads(z.read("stats.json"))
    print(case, repr(args), {k: stats[k] for k in ("rmse", "mean", "median", "std", "min", "max", "sse")})
PY
