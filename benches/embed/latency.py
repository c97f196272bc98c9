"""The Python side of `cargo bench --bench embed` (benches/embed.rs): loads a
checkpoint, fills the window, then times TICKS control ticks of Predictor.push +
Predictor.predict_latest and prints the seconds they took. With a third argument,
each tick is timed on its own instead: the times (uint64 ns, native byte order) go to
that file, frames are cycled from CYCLE made beforehand, and it prints
"tail RSS_BEFORE RSS_AFTER FAULTS" (VmRSS in KiB after the warm-up and after the run,
minor page faults during it).

    python latency.py MODEL.safetensors TICKS [TICKS_FILE]
"""

import math
import resource
import sys
import time

import numpy as np

import iastgcn


def sensor(node: int, tick: int) -> float:
    if tick % (1 + node % 4) != 0:
        return math.nan
    phase = (tick * (node + 1) * 7 + node * 13) % 200
    return 20.0 + node + 0.5 * abs(float(phase) - 100.0) / 100.0


CYCLE = 1200


def rss_kib() -> int:
    """VmRSS of this process, KiB (0 where /proc has none)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmRSS:"):
                    return int(line.split()[1])
    except OSError:
        pass
    return 0


def tail(p: "iastgcn.Predictor", nodes: int, window: int, ticks: int, path: str) -> None:
    """The long run: every tick timed on its own, the times written to `path`."""
    frames = [np.array([sensor(n, t) for n in range(nodes)]) for t in range(CYCLE)]
    # Written before the run, so that the run touches no new page of it.
    ns = np.ones(ticks, dtype=np.uint64)
    for t in range(window + 10):
        p.push(frames[t % CYCLE])
        p.predict_latest()
    before = rss_kib()
    clock = time.perf_counter_ns
    clock()  # the clock's pages touched before the count
    faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
    total = 0.0
    for t in range(ticks):
        frame = frames[(window + 10 + t) % CYCLE]
        began = clock()
        p.push(frame)
        total += p.predict_latest()[0]
        ns[t] = clock() - began
    faults = resource.getrusage(resource.RUSAGE_SELF).ru_minflt - faults
    after = rss_kib()
    ns.tofile(path)
    print(f"tail {before} {after} {faults} {total}")


def main() -> None:
    ticks = int(sys.argv[2])
    p = iastgcn.Predictor(sys.argv[1], dt=0.02)
    nodes, _, window = p.window_shape
    if len(sys.argv) > 3:
        tail(p, nodes, window, ticks, sys.argv[3])
        return
    # The frames are made outside the timing: the loop measures the binding, not the
    # synthetic signal.
    frames = [np.array([sensor(n, t) for n in range(nodes)]) for t in range(window + 10 + ticks)]
    for t in range(window + 10):
        p.push(frames[t])
        p.predict_latest()
    total = 0.0
    began = time.perf_counter()
    for t in range(window + 10, window + 10 + ticks):
        p.push(frames[t])
        total += p.predict_latest()[0]
    seconds = time.perf_counter() - began
    print(f"{seconds:.9f} {total}")


if __name__ == "__main__":
    main()
