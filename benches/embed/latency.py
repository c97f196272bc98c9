"""The Python side of `cargo bench --bench embed` (benches/embed.rs): loads a
checkpoint, fills the window, then times TICKS control ticks of Predictor.push +
Predictor.predict_latest and prints the seconds they took.

    python latency.py MODEL.safetensors TICKS
"""

import math
import sys
import time

import numpy as np

import iastgcn


def sensor(node: int, tick: int) -> float:
    if tick % (1 + node % 4) != 0:
        return math.nan
    phase = (tick * (node + 1) * 7 + node * 13) % 200
    return 20.0 + node + 0.5 * abs(float(phase) - 100.0) / 100.0


def main() -> None:
    ticks = int(sys.argv[2])
    p = iastgcn.Predictor(sys.argv[1], dt=0.02)
    nodes, _, window = p.window_shape
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
