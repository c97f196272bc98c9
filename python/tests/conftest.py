"""Fixtures of the pytest suite: the engine's binaries built by `cargo test` (the
`iastgcn` command and the Rust examples), and checkpoints made with them."""

import json
import os
import struct
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="session")
def profile_dir() -> Path:
    """Where cargo put the binaries (IASTGCN_PROFILE_DIR, default target/debug)."""
    d = ROOT / os.environ.get("IASTGCN_PROFILE_DIR", "target/debug")
    for exe in (d / "iastgcn", d / "examples" / "controller"):
        if not exe.exists():
            pytest.fail(f"{exe} is missing: run `cargo test` (or `make test`) first")
    return d


def cli(profile_dir: Path, *args: str) -> str:
    """Runs the `iastgcn` command; fails the test with its stderr on failure."""
    run = subprocess.run(
        [str(profile_dir / "iastgcn"), *args], capture_output=True, text=True
    )
    if run.returncode != 0:
        pytest.fail(f"iastgcn {' '.join(args)} failed:\n{run.stderr}")
    return run.stdout


def set_statistics(path: Path) -> None:
    """Rewrites a checkpoint's normalisation (safetensors metadata) to statistics that
    are not the identity: the same ones as tests/c_abi.rs."""
    data = path.read_bytes()
    (length,) = struct.unpack("<Q", data[:8])
    header = json.loads(data[8 : 8 + length])
    meta = header["__metadata__"]
    nodes = len(json.loads(meta["normalization"])["feature_mean"])
    meta["normalization"] = json.dumps(
        {
            "feature_mean": [[20.0 + n, 0.001, 0.5] for n in range(nodes)],
            "feature_std": [[0.3, 0.01, 0.2] for _ in range(nodes)],
            "label_mean": [5.0, -3.0, 2.0, 1.0, -1.0, 0.5],
            "label_std": [30.0, 20.0, 10.0, 5.0, 4.0, 3.0],
        }
    )
    text = json.dumps(header).encode()
    text += b" " * (-len(text) % 8)
    path.write_bytes(struct.pack("<Q", len(text)) + text + data[8 + length :])


@pytest.fixture(scope="session")
def checkpoint(profile_dir: Path, tmp_path_factory) -> Path:
    """An initialised checkpoint of the demo's shape (17 nodes: the sensors and the planned motion, 3 features, T = 48)."""
    out = tmp_path_factory.mktemp("model") / "model.safetensors"
    cli(profile_dir, "init", "--config", str(ROOT / "assets/demo.toml"), "--seed", "5",
        "--out", str(out))
    set_statistics(out)
    return out
