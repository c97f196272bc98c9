"""The engine's dwell-time solver (src/polish/dwell.rs, `DwellSolver::solve`) in NumPy, run
on the problems `cargo bench --bench polish` wrote (target/bench-polish/dwell_<n>.safetensors)
so that both solve the same problem on the same cores in the same call (`make bench-polish`).

It checks that it finds the engine's seconds (the solution saved in the file), times itself
(the median of --repeats solves), reads criterion's estimate of the engine's solve
(target/criterion/dwell_solve/<n>/new/estimates.json), and writes
target/bench-polish/compare.md. The algorithm, step for step as the engine's: the removal is
the kernel convolved with gain · dwell density on a zero-padded square (FFT), a thresholded
inverse filter below the passes' Nyquist frequency turns the residual on the glass into a
dwell correction, read back along the path, relaxed and clipped to the feed limits; four
thresholds, eight iterations each, the iterate with the least RMS over the clear aperture
kept. Written as a NumPy user would: whole-array operations, numpy.fft, np.bincount for the
path's cells.
"""

import argparse
import json
import os
import struct
import sys
import time

import numpy as np

DTYPES = {"F64": "<f8", "I64": "<i8", "U8": "u1"}


def read_safetensors(path):
    with open(path, "rb") as f:
        raw = f.read()
    (size,) = struct.unpack("<Q", raw[:8])
    header = json.loads(raw[8 : 8 + size])
    meta = header.pop("__metadata__", {})
    data = raw[8 + size :]
    tensors = {}
    for name, t in header.items():
        a, b = t["data_offsets"]
        tensors[name] = np.frombuffer(data[a:b], dtype=DTYPES[t["dtype"]]).reshape(t["shape"])
    return tensors, meta


class Problem:
    def __init__(self, path):
        t, m = read_safetensors(path)
        self.n = int(m["n"])
        self.reach = int(m["reach"])
        self.pitch = float(m["pitch"])
        self.cutoff = float(m["cutoff"])
        self.iterations = int(m["iterations"])
        self.relaxation = float(m["relaxation"])
        self.gammas = [float(g) for g in m["gammas"].split(",")]
        self.engine_gamma = float(m["gamma"])
        self.engine_planned_rms = float(m["planned_rms"])
        self.kernel = t["kernel"]
        self.gain = t["gain"].ravel()
        self.measured = t["measured"].ravel()
        self.glass = t["glass"].ravel().astype(bool)
        self.clear = t["clear"].ravel().astype(bool)
        starts = t["segment_start"]
        self.pixel = t["cell_pixel"]
        self.weight = t["cell_weight"]
        self.segments = len(starts) - 1
        self.segment = np.repeat(np.arange(self.segments), np.diff(starts))
        self.bounds = t["bounds"]
        self.area = t["area"]
        self.engine_seconds = t["seconds"]


class Solver:
    def __init__(self, p):
        self.p = p
        n, reach = p.n, p.reach
        self.size = size = n + 2 * reach
        padded = np.zeros((size, size))
        padded[: 2 * reach + 1, : 2 * reach + 1] = p.kernel
        # The kernel's centre at (0, 0), negative offsets wrapped to the far end.
        self.spectrum = np.fft.fft2(np.roll(padded, (-reach, -reach), axis=(0, 1)))
        k = np.minimum(np.arange(size), size - np.arange(size)) / size
        self.radial = np.hypot(k[:, None], k[None, :])
        self.weight_sum = np.bincount(p.segment, weights=p.weight, minlength=p.segments)

    def filter(self, values, spectrum_factor):
        n = self.p.n
        work = np.zeros((self.size, self.size))
        work[:n, :n] = values.reshape(n, n)
        out = np.fft.ifft2(np.fft.fft2(work) * spectrum_factor)
        return out[:n, :n].real.ravel()

    def removal(self, t):
        return self.filter(t * self.p.gain, self.spectrum)

    def dwell_map(self, seconds):
        p = self.p
        values = p.weight * seconds[p.segment] / (p.pitch * p.pitch)
        return np.bincount(p.pixel, weights=values, minlength=p.n * p.n)

    def sample(self, values):
        p = self.p
        sums = np.bincount(p.segment, weights=p.weight * values[p.pixel], minlength=p.segments)
        return np.divide(sums, self.weight_sum, out=np.zeros_like(sums), where=self.weight_sum > 0)

    def rms_left(self, removal):
        left = (self.p.measured - removal)[self.p.clear]
        return np.sqrt(np.mean((left - left.mean()) ** 2))

    def solve(self):
        p = self.p
        lowest = p.measured[p.clear].min()
        least = p.bounds[:, 0].copy()
        floor = self.removal(self.dwell_map(least))
        layer = max(0.0, np.max((floor - (p.measured - lowest))[p.clear]))
        wanted = np.where(p.glass, p.measured - lowest + layer, 0.0)
        gain = self.sample(p.gain)
        largest = np.abs(self.spectrum).max()
        best = (self.rms_left(floor), least.copy(), float("nan"))
        for gamma in p.gammas:
            keep = (np.abs(self.spectrum) >= gamma * largest) & (self.radial <= p.cutoff)
            inverse = np.zeros_like(self.spectrum)
            inverse[keep] = 1.0 / self.spectrum[keep]
            seconds = least.copy()
            for _ in range(p.iterations + 1):
                removal = self.removal(self.dwell_map(seconds))
                rms = self.rms_left(removal)
                if rms < best[0]:
                    best = (rms, seconds.copy(), gamma)
                residual = np.where(p.glass, wanted - removal, 0.0)
                along = self.sample(self.filter(residual, inverse))
                seconds = np.clip(
                    seconds + p.relaxation * along * p.area / gain, p.bounds[:, 0], p.bounds[:, 1]
                )
        return best


def engine_seconds(root, n):
    path = os.path.join(root, "criterion", "dwell_solve", str(n), "new", "estimates.json")
    try:
        with open(path) as f:
            e = json.load(f)
    except OSError:
        return None
    return e["median"]["point_estimate"] * 1e-9


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--dir", default="target/bench-polish")
    ap.add_argument("--criterion", default="target")
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    rows, failed = [], False
    for n in (512, 1024):
        path = os.path.join(args.dir, f"dwell_{n}.safetensors")
        if not os.path.exists(path):
            sys.exit(f"{path}: missing; run `cargo bench --bench polish` first")
        p = Problem(path)
        solver = Solver(p)
        times = []
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            rms, seconds, gamma = solver.solve()
            times.append(time.perf_counter() - t0)
        scale = np.abs(p.engine_seconds).max()
        diff = np.abs(seconds - p.engine_seconds).max() / scale
        agree = diff < 1e-6 and gamma == p.engine_gamma
        failed |= not agree
        numpy_s = float(np.median(times))
        engine_s = engine_seconds(args.criterion, n)
        ratio = f"{engine_s / numpy_s:.2f}" if engine_s else "n/a"
        print(
            f"{n} x {n}: NumPy {numpy_s:.3f} s, engine {engine_s if engine_s else float('nan'):.3f} s "
            f"(engine / NumPy {ratio}); planned RMS {rms:.4f} nm against the engine's "
            f"{p.engine_planned_rms:.4f}, gamma {gamma} against {p.engine_gamma}, seconds differ "
            f"by at most {diff:.1e} of the largest"
        )
        rows.append((n, p.segments, numpy_s, engine_s, ratio, rms, p.engine_planned_rms, diff, agree))
    lines = [
        "# The dwell solve: the engine against NumPy on the same problem",
        "",
        f"NumPy {np.__version__}, Python {sys.version.split()[0]}, {os.cpu_count()} CPUs; engine: "
        "criterion's median of `cargo bench --bench polish` (dwell_solve) run just before.",
        "",
        "| map | segments | NumPy (s, median) | engine (s, median) | engine / NumPy | planned RMS NumPy / engine (nm) | seconds agree (max rel. diff) |",
        "|---|---:|---:|---:|---:|---|---|",
    ]
    for n, segs, numpy_s, engine_s, ratio, rms, erms, diff, agree in rows:
        engine = f"{engine_s:.3f}" if engine_s else "n/a"
        lines.append(
            f"| {n} × {n} | {segs} | {numpy_s:.3f} | {engine} | {ratio} | {rms:.4f} / {erms:.4f} | "
            f"{'yes' if agree else 'NO'} ({diff:.1e}) |"
        )
    out = os.path.join(args.dir, "compare.md")
    with open(out, "w") as f:
        f.write("\n".join(lines) + "\n")
    print(f"wrote {out}")
    if failed:
        sys.exit("NumPy and the engine found different dwells: the comparison is void")


if __name__ == "__main__":
    main()
