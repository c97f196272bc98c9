"""The Python Predictor against the Rust one, and its refusals of bad input."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import iastgcn

from conftest import ROOT


def test_controller_example_prints_the_rust_examples_residuals_bit_for_bit(
    profile_dir: Path, checkpoint: Path
):
    def run(*command):
        done = subprocess.run([*command, str(checkpoint), "70"], capture_output=True,
                              text=True)
        assert done.returncode == 0, done.stderr
        return done.stdout

    rust = run(str(profile_dir / "examples" / "controller"))
    python = run(sys.executable, str(ROOT / "examples/python/controller.py"))
    # T = 48: ticks 47..69 predict, after the shape line.
    assert len(rust.splitlines()) == 1 + 23
    assert python == rust


def test_shapes_names_and_repr(checkpoint: Path):
    p = iastgcn.Predictor(checkpoint, dt=0.02)
    assert p.window_shape == (17, 3, 48)
    assert p.look_ahead == 1
    assert p.nodes[:3] == ["E1", "E2", "E3"] and len(p.nodes) == 17
    assert p.variant == "iastgcn"
    assert p.backend == "native"
    assert p.dt == 0.02
    assert p.threads == 1
    p.threads = 2
    assert p.threads == 2
    assert "nodes=17" in repr(p)
    assert iastgcn.Predictor(checkpoint).dt is None
    assert iastgcn.__version__.count(".") == 2


def random_windows(count: int, seed: int = 3) -> np.ndarray:
    rng = np.random.default_rng(seed)
    means = np.array([[20.0 + n, 0.001, 0.5] for n in range(17)])[None, :, :, None]
    return (means + rng.normal(0.0, 0.2, (count, 17, 3, 48))).astype(np.float32)


def test_batches_single_windows_and_dtypes_agree(checkpoint: Path):
    p = iastgcn.Predictor(checkpoint)
    windows = random_windows(5)
    batch = p.predict_batch(windows)
    assert batch.shape == (5, 6) and batch.dtype == np.float64
    for w, expected in zip(windows, batch):
        assert np.array_equal(p.predict(w), expected)
    # float64 in is cast to the model's float32: the same numbers.
    assert np.array_equal(p.predict_batch(windows.astype(np.float64)), batch)
    # A non-contiguous view is copied, not refused.
    transposed = np.ascontiguousarray(windows.transpose(3, 1, 2, 0)).transpose(3, 1, 2, 0)
    assert not transposed.flags["C_CONTIGUOUS"]
    assert np.array_equal(p.predict_batch(transposed), batch)
    # Already standardised windows skip the checkpoint's statistics.
    mean = np.array([[20.0 + n, 0.001, 0.5] for n in range(17)], np.float64)[:, :, None]
    std = np.array([[0.3, 0.01, 0.2]] * 17, np.float64)[:, :, None]
    standardised = ((windows.astype(np.float64) - mean) / std).astype(np.float32)
    assert np.allclose(p.predict_batch(standardised, standardised=True), batch, rtol=1e-4,
                       atol=1e-3)


def test_pushed_feature_steps_give_the_window_residual(checkpoint: Path):
    p = iastgcn.Predictor(checkpoint)
    window = random_windows(1)[0]
    for t in range(48):
        assert p.predict_latest() is None
        full = p.push_features(window[:, :, t])
        assert full == (t == 47)
    assert np.array_equal(p.predict_latest(), p.predict(window))
    # Flat steps work too; reset forgets.
    p.reset()
    assert p.predict_latest() is None
    for t in range(48):
        p.push_features(window[:, :, t].reshape(-1))
    assert np.array_equal(p.predict_latest(), p.predict(window))


def test_sensor_frames_accept_lists_and_hold_missing_samples(checkpoint: Path):
    a = iastgcn.Predictor(checkpoint, dt=0.02)
    b = iastgcn.Predictor(checkpoint, dt=0.02)
    frame = [20.0 + n for n in range(17)]
    for tick in range(50):
        a.push(np.array(frame, dtype=np.float32))
        # NaN holds the last sample: the same as repeating it in float32.
        b.push([v if tick == 0 or n % 2 else np.nan for n, v in
                enumerate(np.array(frame, np.float32).astype(float))])
    assert np.array_equal(a.predict_latest(), b.predict_latest())


def test_bad_input_raises_iastgcn_error_with_the_engines_message(checkpoint: Path, tmp_path):
    assert issubclass(iastgcn.Error, Exception)
    with pytest.raises(iastgcn.Error, match="missing.safetensors"):
        iastgcn.Predictor(tmp_path / "missing.safetensors")
    with pytest.raises(iastgcn.Error, match="backend"):
        iastgcn.Predictor(checkpoint, backend="gpu")
    with pytest.raises(iastgcn.Error, match="threads"):
        iastgcn.Predictor(checkpoint, threads=0)
    with pytest.raises(iastgcn.Error, match="dt"):
        iastgcn.Predictor(checkpoint, dt=-1.0)
    p = iastgcn.Predictor(checkpoint, dt=0.02)
    with pytest.raises(iastgcn.Error, match=r"frame: expected shape \[17\], got \[13\]"):
        p.push(np.zeros(13))
    with pytest.raises(iastgcn.Error, match="window: expected shape"):
        p.predict(np.zeros((17, 3, 47)))
    with pytest.raises(iastgcn.Error, match=r"windows: expected shape \(W, 17, 3, 48\)"):
        p.predict_batch(np.zeros((2, 17, 48, 3)))
    with pytest.raises(iastgcn.Error, match="step: expected shape"):
        p.push_features(np.zeros((3, 17)))
    features_only = iastgcn.Predictor(checkpoint)
    with pytest.raises(iastgcn.Error, match="without a control period"):
        features_only.push(np.zeros(17))
    with pytest.raises(iastgcn.Error, match="threads"):
        p.threads = 0
    not_a_checkpoint = tmp_path / "notes.safetensors"
    not_a_checkpoint.write_text("hello")
    with pytest.raises(iastgcn.Error, match="notes.safetensors"):
        iastgcn.Predictor(not_a_checkpoint)


def test_ensemble_files_average_their_members_and_give_intervals(
    profile_dir: Path, checkpoint: Path, tmp_path
):
    from conftest import cli, set_statistics

    second = tmp_path / "second.safetensors"
    cli(profile_dir, "init", "--config", str(ROOT / "assets/demo.toml"), "--seed", "6",
        "--out", str(second))
    set_statistics(second)
    ensemble = tmp_path / "m.ensemble.toml"
    ensemble.write_text(
        f'members = ["{checkpoint}", "second.safetensors"]\n\n'
        "[interval]\nlevel = 0.9\nposition = { constant = 30.0 }\n"
        "attitude = { scale = 2.0 }\n"
    )
    e = iastgcn.Predictor(ensemble, dt=0.02)
    assert e.members == 2 and e.interval_level == 0.9
    assert e.interval() is None, "no prediction yet"
    a = iastgcn.Predictor(checkpoint, dt=0.02)
    b = iastgcn.Predictor(second, dt=0.02)
    assert a.members == 1 and a.interval() is None and a.interval_level is None
    for tick in range(50):
        frame = [20.0 + n + 0.3 * np.sin(0.07 * tick * (n + 1)) for n in range(17)]
        for p in (a, b, e):
            p.push(frame)
    ra, rb, r = a.predict_latest(), b.predict_latest(), e.predict_latest()
    assert np.allclose(r, (ra + rb) / 2, rtol=1e-12, atol=1e-12)
    position, attitude = e.interval()
    assert position == 30.0
    # Two members: each is half their distance from the mean.
    assert np.isclose(attitude, 2.0 * np.linalg.norm(ra[3:] - rb[3:]) / 2, rtol=1e-12)
    with pytest.raises(iastgcn.Error, match="ensemble"):
        e.predict(np.zeros((17, 3, 48)))
    with pytest.raises(iastgcn.Error, match="dt"):
        iastgcn.Predictor(ensemble)
