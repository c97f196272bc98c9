#!/usr/bin/env python3
"""The look-ahead study folders' records with the floor that applies (issue 73, item 1;
docs/look-ahead/README.md "The floor that applies"). `rescore.sh` moves a folder's job
records aside into OLD/ and runs `scale` again, which resumes every finished training and
scores it again with this build; then this script checks, for each record, that every
field but `oracle`, `wall_seconds` and `closed_loop` came out the same (the models, the
closed-loop data and the held-out runs are the ones of the first run), and writes the
original record with the new `oracle` lines in place of the rescored one (it keeps the
training's wall time and the closed-loop round's description, which a resumed run cannot
know).

    python3 docs/look-ahead/rescore.py FOLDER OLD
"""
import math
import os
import re
import sys
import tomllib
from pathlib import Path

KEPT = {"wall_seconds", "closed_loop", "paths"}


def same(a, b):
    if isinstance(a, float) and isinstance(b, float) and math.isnan(a) and math.isnan(b):
        return True
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(same(x, y) for x, y in zip(a, b))
    return a == b


def differences(old, new):
    out = [k for k in set(old) | set(new) if k not in KEPT and not same(old.get(k), new.get(k))]
    if len(old["paths"]) != len(new["paths"]):
        return out + ["paths"]
    for a, b in zip(old["paths"], new["paths"]):
        out += [(a["path"], a.get("session"), k) for k in set(a) | set(b)
                if k != "oracle" and not same(a.get(k), b.get(k))]
    return out


def main(folder, old_dir):
    for old in sorted(Path(old_dir).glob("*.job.toml")):
        new = Path(folder, "models", old.name)
        o, n = old.read_text(), new.read_text()
        diff = differences(tomllib.loads(o), tomllib.loads(n))
        if diff:
            sys.exit(f"{new}: differs from {old} beyond the oracle: {diff}")
        oracles = re.findall(r"^oracle = .*$", n, re.M)
        parts = re.split(r"^oracle = .*$", o, flags=re.M)
        assert len(parts) == len(oracles) + 1, old
        merged = parts[0] + "".join(f"{line}{rest}" for line, rest in zip(oracles, parts[1:]))
        tmp = new.with_suffix(".tmp")
        tmp.write_text(merged)
        os.replace(tmp, new)
        print(f"{new}: the same but the oracle ({len(oracles)} runs); written")


if __name__ == "__main__":
    main(sys.argv[1], sys.argv[2])
