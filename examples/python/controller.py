"""A controller loop in Python: load a checkpoint once, then each control tick push the
raw sensor values and read the residual to compensate. It prints the same lines as the
Rust example (examples/controller.rs), bit for bit; the pytest suite checks it.

    python examples/python/controller.py MODEL.safetensors [TICKS]

The sensor values are synthetic (a triangle wave per node, some nodes sampled only every
few ticks: NaN in between), computed with exact operations so that every language gets
the same doubles.
"""

import math
import struct
import sys

import numpy as np

import iastgcn

# The control period of the twin's recordings, s.
DT = 0.02


def sensor(node: int, tick: int) -> float:
    """Node `node`'s sensor value at tick `tick`, or NaN when it has no new sample."""
    if tick % (1 + node % 4) != 0:
        return math.nan
    phase = (tick * (node + 1) * 7 + node * 13) % 200
    triangle = abs(float(phase) - 100.0) / 100.0
    return 20.0 + float(node) + 0.5 * triangle


def line(tick: int, r: np.ndarray) -> str:
    """One output line: the residual, then the bits of its six doubles in hex."""
    bits = " ".join(f"{struct.unpack('<Q', struct.pack('<d', v))[0]:016x}" for v in r)
    values = "{:9.3f} {:9.3f} {:9.3f} um  {:9.3f} {:9.3f} {:9.3f} mdeg".format(*r)
    return f"tick {tick:4d}  {values} | {bits}"


def main() -> int:
    if len(sys.argv) < 2:
        print("usage: controller.py MODEL.safetensors [TICKS]", file=sys.stderr)
        return 2
    ticks = int(sys.argv[2]) if len(sys.argv) > 2 else 60
    # Everything is allocated and warmed up here, once.
    predictor = iastgcn.Predictor(sys.argv[1], dt=DT)
    nodes, features, window = predictor.window_shape
    print(f"nodes {nodes} features {features} window {window}")
    frame = np.empty(nodes)
    for tick in range(ticks):
        for node in range(nodes):
            frame[node] = sensor(node, tick)
        predictor.push(frame)
        r = predictor.predict_latest()
        if r is not None:
            print(line(tick, r))
    return 0


if __name__ == "__main__":
    sys.exit(main())
