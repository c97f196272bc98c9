"""The engine against PyTorch on the same CPU, in one run (`make bench-compare`).

1. Interop: for each IASTGCN variant and both shapes, `iastgcn init` writes a
   checkpoint, every tensor of it is perturbed (so that biases, theta, be, bs and the
   LayerNorm affine are not at their neutral start), `iastgcn forward` runs it on random
   windows, and the PyTorch model of iastgcn_torch.py, loaded from the same file, must
   give the same outputs to 1e-4 (max |difference|, standardised label space).
2. Speed: the engine's `cargo bench --bench model` groups for the two shapes (the WGSL
   path on the adapter, and also the native CPU path: forward at B = 1 and the
   training step at B = 64; criterion,
   its summary written as CSV through IASTGCN_BENCH_CSV) and the same three measurements
   in PyTorch (forward B = 1 and B = 64 under no_grad in eval mode; a training step at
   B = 64: forward with dropout, the eq. 39 data loss, backward, no optimiser, exactly
   what the engine's step does), plus each side's matmul on the engine's baseline
   product. Both use every core by default (`--threads`).

Prints one table of ratios and writes it with the raw timings to --out (markdown and
JSON). GFLOP/s for both sides use the engine's FLOP count of the network (`model::flops`,
the contractions of the schedule), so they compare work done per second on the same
problem, not each framework's own operation count.
"""

import argparse
import csv
import datetime
import json
import os
import platform
import re
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import torch
from safetensors.numpy import load_file, save_file
from safetensors import safe_open

sys.path.insert(0, str(Path(__file__).resolve().parent))
from iastgcn_torch import VARIANTS, load_checkpoint  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
BATCH = 64
# (label, engine bench group, run config). The small shape is the model bench's
# (benches/common `small_config`: the demo's C and T at L = 3), written out here because
# assets/demo.toml trains at L = 2.
SMALL_CONFIG = "[model]\nchannels = 16\nwindow = 48\nblocks = 3\n"
SHAPES = [
    ("small C16 T48 L3", "small C16 T48 L3", "small.toml"),
    ("paper C64 T100 L5", "paper C64 T100 L5", "assets/paper.toml"),
]
MEASURES = ["forward B=1", "forward B=64", "train step B=64"]
# Engine rows: the device's three, plus the native CPU forward (model::NativeForward, on
# one thread and with one window split over every core) against the same
# PyTorch forward at B = 1 and the native training step
# (model::NativeTraining, gradients only) against PyTorch's step.
ENGINE_ROWS = [("forward B=1", "forward B=1"), ("native forward B=1", "forward B=1"),
               ("native forward B=1 all cores", "forward B=1"),
               ("forward B=64", "forward B=64"), ("train step B=64", "train step B=64"),
               ("native train step B=64", "train step B=64")]
TOLERANCE = 1e-4


def config_path(config, work):
    """A shape's run config: a file of the repository, or the small shape's own."""
    if config == "small.toml":
        path = work / config
        if not path.exists():
            path.write_text(SMALL_CONFIG)
        return path
    return ROOT / config


def run(cmd, **kw):
    print("+", " ".join(str(c) for c in cmd), flush=True)
    return subprocess.run(cmd, check=True, cwd=ROOT, **kw)


def interop(binary, work):
    """Engine forward against the PyTorch model on shared weights; returns rows."""
    rng = np.random.default_rng(7)
    rows = []
    for label, _, config in SHAPES:
        for variant in VARIANTS:
            base = work / f"{variant}-{label.split()[0]}"
            ckpt, perturbed = base.with_suffix(".init.safetensors"), base.with_suffix(".safetensors")
            run([binary, "init", "--config", config_path(config, work), "--variant", variant, "--seed", "3",
                 "--out", ckpt],
                stdout=subprocess.DEVNULL)
            with safe_open(ckpt, framework="np") as f:
                meta = f.metadata()
            tensors = load_file(ckpt)
            for name, t in tensors.items():
                tensors[name] = (t + rng.uniform(-0.1, 0.1, t.shape) * (1 + np.abs(t))).astype(np.float32)
            save_file(tensors, perturbed, metadata=meta)
            cfg = json.loads(meta["config"])
            x = rng.standard_normal((5, cfg["nodes"], cfg["features"], cfg["window"])).astype(np.float32)
            xin, yout = base.with_suffix(".x.safetensors"), base.with_suffix(".y.safetensors")
            save_file({"x": x}, xin)
            run([binary, "forward", "--model", perturbed, "--input", xin, "--out", yout, "--batch", "5"],
                stdout=subprocess.DEVNULL)
            engine = load_file(yout)["y"]
            with torch.no_grad():
                ours = load_checkpoint(perturbed)(torch.from_numpy(x)).numpy()
            diff = float(np.abs(engine.astype(np.float64) - ours).max())
            scale = float(np.abs(ours).max())
            rows.append((label, variant, diff, scale))
            print(f"interop {label} {variant}: max |engine - torch| = {diff:.2e} (outputs up to {scale:.2f})")
    return rows


def time_call(fn, min_seconds=3.0, min_iters=5, sync=lambda: None):
    """Mean seconds per call after one warm-up call, over at least min_iters calls and
    min_seconds (at most 10 calls when one takes over 2 s). `sync` waits for queued work
    (a CUDA device's), so that the clock stops when the work is done."""
    fn()
    sync()
    t0 = time.perf_counter()
    fn()
    sync()
    once = time.perf_counter() - t0
    iters = 10 if once > 2.0 else max(min_iters, int(min_seconds / max(once, 1e-6)))
    t0 = time.perf_counter()
    for _ in range(iters):
        fn()
    sync()
    return (time.perf_counter() - t0) / iters, iters


def torch_timings(binary, work, device):
    """PyTorch on `device` ("cpu" or "cuda"): seconds per call for each shape and
    measure, and the baseline matmul."""
    dev = torch.device(device)
    sync = torch.cuda.synchronize if dev.type == "cuda" else (lambda: None)
    out = {}
    for label, _, config in SHAPES:
        ckpt = work / f"speed-{label.split()[0]}.safetensors"
        run([binary, "init", "--config", config_path(config, work), "--seed", "1", "--out", ckpt],
            stdout=subprocess.DEVNULL)
        model = load_checkpoint(ckpt).to(dev)
        cfg = model.cfg
        shape = (cfg["nodes"], cfg["features"], cfg["window"])
        x1, x64 = torch.randn(1, *shape, device=dev), torch.randn(BATCH, *shape, device=dev)
        y64 = torch.randn(BATCH, cfg["outputs"], device=dev)

        def forward(x):
            with torch.no_grad():
                model(x)

        def train_step():
            model.zero_grad(set_to_none=True)
            loss = ((model(x64) - y64) ** 2).sum(1).mean()
            loss.backward()

        model.eval()
        out[(label, "forward B=1")] = time_call(lambda: forward(x1), sync=sync)
        out[(label, "forward B=64")] = time_call(lambda: forward(x64), sync=sync)
        model.train()
        out[(label, "train step B=64")] = time_call(train_step, sync=sync)
        for m in MEASURES:
            print(f"torch {label} {m}: {out[(label, m)][0] * 1e3:.2f} ms ({out[(label, m)][1]} calls)")
    a, b = torch.randn(64, 192, device=dev), torch.randn(896, 192, 100, device=dev)
    c = torch.empty(896, 64, 100, device=dev)
    out["matmul"] = time_call(lambda: torch.matmul(a, b, out=c), sync=sync)
    return out


def engine_timings(csv_path, skip):
    """Runs the engine's model bench for the two shapes and the baseline; reads its CSV."""
    if not skip:
        groups = ["baseline"] + [s[1] for s in SHAPES]
        env = dict(os.environ, IASTGCN_BENCH_CSV=str(csv_path), IASTGCN_BENCH_GROUPS=",".join(groups))
        run(["cargo", "bench", "--bench", "model"], env=env)
    rows = {}
    with open(csv_path) as f:
        for r in csv.DictReader(f):
            rows[r["benchmark"]] = (float(r["mean_s"]), float(r["flops"]))
    return rows


def peak_estimate():
    """fp32 peak from /proc/cpuinfo: cores x clock x FLOPs per cycle per core (two FMA
    pipes: 64 with AVX-512F, 32 with AVX2+FMA, 16 with AVX, 8 otherwise). An estimate,
    not a measurement: Xeons with a single AVX-512 FMA unit peak at half the AVX-512
    figure, and /proc/cpuinfo cannot tell them apart."""
    try:
        info = Path("/proc/cpuinfo").read_text()
    except OSError:
        return None, platform.processor() or "unknown CPU"
    name = re.search(r"model name\s*:\s*(.*)", info)
    mhz = [float(m) for m in re.findall(r"cpu MHz\s*:\s*([\d.]+)", info)]
    flags = re.search(r"flags\s*:\s*(.*)", info)
    flags = set(flags.group(1).split()) if flags else set()
    if "avx512f" in flags:
        per_cycle = 64
    elif {"avx2", "fma"} <= flags:
        per_cycle = 32
    else:
        per_cycle = 16 if "avx" in flags else 8
    cores = os.cpu_count() or 1
    cpu = f"{name.group(1) if name else 'unknown CPU'}, {cores} cores"
    if not mhz:
        return None, cpu
    clock = sum(mhz) / len(mhz)
    return cores * clock * 1e6 * per_cycle / 1e9, f"{cpu} at {clock:.0f} MHz ({per_cycle} FLOP/cycle/core)"


def main():
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--out", type=Path, default=ROOT / "target" / "bench-compare")
    p.add_argument("--threads", type=int, default=os.cpu_count())
    p.add_argument("--check-only", action="store_true", help="interop check only, no timings")
    p.add_argument("--engine-csv", type=Path, help="reuse an engine CSV instead of running cargo bench")
    p.add_argument("--torch-device", default="cpu",
                   help="where PyTorch runs: cpu (the comparison on the same CPU) or cuda")
    p.add_argument("--binary", type=Path,
                   help="a built iastgcn binary to use instead of building target/release/iastgcn")
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    if args.torch_device != "cpu" and not torch.cuda.is_available():
        sys.exit(f"--torch-device {args.torch_device}: this PyTorch sees no CUDA device")
    args.out.mkdir(parents=True, exist_ok=True)
    binary = args.binary or ROOT / "target" / "release" / "iastgcn"
    if args.binary is None:
        run(["cargo", "build", "--release", "--bin", "iastgcn"])
    with tempfile.TemporaryDirectory() as tmp:
        work = Path(tmp)
        checks = interop(binary, work)
        bad = [r for r in checks if not r[2] <= TOLERANCE]
        if bad:
            for label, variant, diff, _ in bad:
                print(f"FAIL: {label} {variant}: engine and PyTorch differ by {diff:.2e} > {TOLERANCE}")
            sys.exit(1)
        print(f"interop: all {len(checks)} checkpoints agree within {TOLERANCE}")
        if args.check_only:
            return
        pt = torch_timings(binary, work, args.torch_device)
    engine = engine_timings(args.engine_csv or args.out / "engine.csv", args.engine_csv is not None)
    peak, cpu = peak_estimate()
    report(args, pt, engine, peak, cpu, checks)


def report(args, pt, engine, peak, cpu, checks):
    if args.torch_device == "cpu":
        title = "on the same CPU"
        where = f"PyTorch on {args.threads} threads"
    else:
        title = f"on {torch.cuda.get_device_name()}"
        where = f"PyTorch on {torch.cuda.get_device_name()} (CUDA)"
    lines = [
        f"# Engine vs PyTorch {torch.__version__} {title}",
        "",
        f"{datetime.date.today()}, {cpu}; {where}; engine on "
        f"whatever adapter `iastgcn info` picks (native rows: the CPU's cores); batch {BATCH}. "
        "CPU fp32 peak estimate: " + (f"{peak:.0f} GFLOP/s." if peak else "unknown."),
        "GFLOP/s on both sides use the engine's FLOP count of the network.",
        "",
        "| shape | measure | engine | PyTorch | engine / PyTorch time | engine GFLOP/s | PyTorch GFLOP/s |",
        "|---|---|---|---|---|---|---|",
    ]
    data = {"date": str(datetime.date.today()), "cpu": cpu, "peak_gflops": peak, "torch": torch.__version__,
            "torch_device": args.torch_device, "threads": args.threads, "rows": [], "interop": checks}
    for label, group, _ in SHAPES:
        for m, torch_m in ENGINE_ROWS:
            key = f"{group}/{m}"
            if key not in engine:
                lines.append(f"| {label} | {m} | not run | | | | |")
                continue
            es, flops = engine[key]
            ts = pt[(label, torch_m)][0]
            lines.append(
                f"| {label} | {m} | {es * 1e3:.1f} ms | {ts * 1e3:.1f} ms | {es / ts:.2f}× | "
                f"{flops / es / 1e9:.2f} | {flops / ts / 1e9:.2f} |"
            )
            data["rows"].append({"shape": label, "measure": m, "engine_s": es, "torch_s": ts, "flops": flops})
    base = [v for k, v in engine.items() if k.startswith("baseline/")]
    if base:
        es, flops = base[0]
        ts = pt["matmul"][0]
        lines.append(
            f"| matmul 896×[64,192]·[192,100] | one product | {es * 1e3:.1f} ms | {ts * 1e3:.1f} ms | "
            f"{es / ts:.2f}× | {flops / es / 1e9:.2f} | {flops / ts / 1e9:.2f} |"
        )
        data["rows"].append({"shape": "matmul", "measure": "baseline", "engine_s": es, "torch_s": ts, "flops": flops})
    worst = max(c[2] for c in checks)
    lines += ["", f"Interop: {len(checks)} perturbed checkpoints (4 variants × 2 shapes), engine and PyTorch "
              f"outputs within {worst:.1e} (limit {TOLERANCE})."]
    text = "\n".join(lines) + "\n"
    print("\n" + text)
    for name, body in [("compare.md", text), ("compare.json", json.dumps(data, indent=1))]:
        tmp = args.out / f".{name}.tmp"
        tmp.write_text(body)
        tmp.replace(args.out / name)
    print(f"wrote {args.out / 'compare.md'} and compare.json")


if __name__ == "__main__":
    main()
