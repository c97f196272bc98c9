"""The demo's steps from Python: the twin's data, the calibrations, training with a
progress callback, refinement and evaluation; each against the command's own output."""

import os
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import iastgcn

from conftest import ROOT, cli


def test_serial_arm_calibration_matches_the_command(profile_dir: Path, tmp_path: Path):
    arm = ROOT / "assets/real-arms/ur5.toml"
    poses = tmp_path / "ur5.csv"
    cli(profile_dir, "import", "--from",
        str(ROOT / "assets/real-arms/3D_UR5_uncalibrated_grid_cleaned.csv"),
        "--out", str(poses), "--pose", "step_order", "--position", "x_t,y_t,z_t",
        "--minus", "x_dif,y_dif,z_dif",
        "--joints", "joint_1,joint_2,joint_3,joint_4,joint_5,joint_6")
    result = iastgcn.calibrate_arm(arm, poses, out=tmp_path / "ur5.calibrated.toml")
    printed = cli(profile_dir, "calibrate", "--robot", str(arm), "--data", str(poses),
                  "--out", str(tmp_path / "cli.toml"))
    # The same file, and the same numbers as the command prints.
    assert (tmp_path / "ur5.calibrated.toml").read_text() == (tmp_path / "cli.toml").read_text()
    assert f"identified {len(result['parameters'])} of" in printed
    for p in result["parameters"]:
        assert re.search(rf"^{re.escape(p['name'])}\s+{p['start']:.5f}\s+{p['calibrated']:.5f}",
                         printed, re.M), p
    held = [r for r in result["errors"] if r["label"].startswith("held out")][0]
    calibrated = result["errors"][result["errors"].index(held) + 1]
    assert calibrated["stage"] == "calibrated"
    assert calibrated["position"]["mean"] < held["position"]["mean"] / 5
    assert result["scored"] == 200 and result["fitted"] == 800
    assert all(k["reason"] for k in result["kept_nominal"])
    with pytest.raises(iastgcn.Error, match="not a serial arm"):
        iastgcn.calibrate_arm(ROOT / "assets/robot.toml", poses)


@pytest.fixture(scope="module")
def twin_data(tmp_path_factory) -> dict:
    """The paper recipe's data at half a minute per path, with every progress event."""
    events = []
    out = tmp_path_factory.mktemp("twin")
    data = iastgcn.record_data(out, minutes=0.5, recipe="paper",
                               progress=lambda *e: events.append(e))
    data["events"] = events
    return data


def test_record_data_reports_progress_and_writes_the_files(twin_data: dict):
    assert [Path(r).name for r in twin_data["recordings"]] == [
        "grid.csv", "fermat.csv", "hilbert.csv"]
    assert all(Path(f).exists() for f in twin_data["recordings"])
    kinds = {e[0] for e in twin_data["events"]}
    assert {"begin", "update", "end", "note"} <= kinds
    notes = [e[1] for e in twin_data["events"] if e[0] == "note"]
    assert any("geometric calibration" in n for n in notes)


def test_record_data_in_sessions_and_its_refusals(tmp_path: Path):
    data = iastgcn.record_data(tmp_path / "s", minutes=0.5, sessions=2, placement="varied",
                               closed_loop=False)
    assert [Path(r).name for r in data["recordings"]] == [
        f"{p}.s0{s}.csv" for s in (1, 2) for p in ("grid", "fermat", "hilbert")]
    assert all(Path(f).exists() for f in data["recordings"])
    assert data["closed_loop"] is None
    # The default recipe records its second half again with a round-0 model compensating
    # (here trained for 2 epochs): the recordings to train on are session 1 open loop and
    # session 2 closed loop.
    config = tmp_path / "round0.toml"
    config.write_text((ROOT / "assets/demo.toml").read_text()
                      .replace("max_epochs = 80", "max_epochs = 2"))
    closed = iastgcn.record_data(tmp_path / "c", minutes=0.5, sessions=2, config=config)
    names = [Path(r).relative_to(tmp_path / "c").as_posix() for r in closed["recordings"]]
    assert names == [f"{p}.s01.csv" for p in ("grid", "fermat", "hilbert")] + [
        f"closed-loop/{p}.s02.csv" for p in ("grid", "fermat", "hilbert")]
    assert all(Path(f).exists() for f in closed["recordings"])
    assert "round 0" in closed["closed_loop"] and "closed loop" in closed["closed_loop"]
    with pytest.raises(iastgcn.Error, match="closed_loop"):
        iastgcn.record_data(tmp_path / "u", minutes=0.5, sessions=1)
    with pytest.raises(iastgcn.Error, match="sessions"):
        iastgcn.record_data(tmp_path / "x", minutes=0.5, sessions=3)
    # The default recipe's 4 sessions need a minute per path or more.
    with pytest.raises(iastgcn.Error, match="sessions"):
        iastgcn.record_data(tmp_path / "w", minutes=0.5)
    with pytest.raises(iastgcn.Error, match="recipe"):
        iastgcn.record_data(tmp_path / "v", minutes=0.5, recipe="single")
    with pytest.raises(iastgcn.Error, match="placement"):
        iastgcn.record_data(tmp_path / "y", minutes=0.5, sessions=2, placement="diagonal")
    with pytest.raises(iastgcn.Error, match="path order"):
        iastgcn.record_data(tmp_path / "z", minutes=0.5, sessions=2, path_order="sideways")
    assert not any((tmp_path / d).exists() for d in ("u", "v", "w", "x", "y", "z"))


def test_hybrid_calibration_matches_the_command(profile_dir: Path, twin_data: dict,
                                               tmp_path: Path):
    measurements = twin_data["calibration_set"]
    result = iastgcn.calibrate(measurements, out=tmp_path / "py.toml",
                               recordings=twin_data["recordings"][:1])
    printed = cli(profile_dir, "calibrate", "--measurements", measurements, "--out",
                  str(tmp_path / "cli.toml"), "--recordings", twin_data["recordings"][0])
    assert (tmp_path / "py.toml").read_text() == (tmp_path / "cli.toml").read_text()
    assert "  identified: " + " ".join(result["identified"]) in printed
    assert [r["stage"] for r in result["errors"]] == ["initial", "calibrated"] * 2
    held = result["errors"][0]
    assert held["label"] == "held-out poses (16)"
    line = f"{held['position']['mean']:8.1f}"
    assert line in printed


def test_training_refinement_and_evaluation_from_python(twin_data: dict, tmp_path: Path):
    events = []
    model = tmp_path / "iastgcn.safetensors"
    trained = iastgcn.train(twin_data["recordings"], twin_data["calibration"], model,
                            config=ROOT / "assets/demo.toml", max_epochs=2,
                            progress=lambda *e: events.append(e))
    assert model.exists()
    assert trained["epochs"] == 2 and len(trained["history"]) == 2
    assert np.isfinite(trained["best_val"])
    assert [m["recording"] for m in trained["test"]] and all(
        m["model"]["count"] > 0 for m in trained["test"])
    assert any(e[0] == "update" for e in events)

    refined = iastgcn.refine(twin_data["recordings"], twin_data["calibration"], model,
                             tmp_path / "refined.safetensors",
                             config=ROOT / "assets/demo.toml")
    assert (tmp_path / "refined.safetensors").exists()
    assert isinstance(refined["verdict"], str) and refined["test_after"]

    # The morning minute: adapted to one recording, judged on its last fifth.
    adapted = iastgcn.adapt(twin_data["recordings"][:1], twin_data["calibration"], model,
                            tmp_path / "today.safetensors", method="offset",
                            config=ROOT / "assets/demo.toml")
    assert (tmp_path / "today.safetensors").exists()
    assert adapted["verdict"].startswith("offset")
    assert adapted["kept_trained"] == (adapted["loss_adapted"] >= adapted["loss_before"])
    assert adapted["windows"][0] > adapted["windows"][1] > 0 and len(adapted["offset"]) == 6
    with pytest.raises(iastgcn.Error, match="sideways"):
        iastgcn.adapt(twin_data["recordings"][:1], twin_data["calibration"], model,
                      tmp_path / "x.safetensors", method="sideways")

    tables = iastgcn.evaluate([model], twin_data["recordings"], twin_data["calibration"],
                              tmp_path / "report", config=ROOT / "assets/demo.toml",
                              held_out_minutes=0.1)
    assert Path(tables["report"]).exists()
    assert {r["model"] for r in tables["table_iii"]} == {"iastgcn", "training mean"}
    assert {(r["stage"], r["model"]) for r in tables["table_v"]} == {
        ("initial", "-"), ("calibrated", "-"), ("compensated", "iastgcn"),
        # The oracle stands in for the model, which looks ahead (assets/demo.toml).
        ("oracle", "true residual, 1 tick(s) ahead")}
    paths = {r["trajectory"] for r in tables["table_v"]}
    assert len(paths) == 4, paths
    # Three held-out sessions by default, each with its own calibrated run of each path.
    assert {r["session"] for r in tables["table_v"]} == {0, 1, 2}
    assert sum(r["stage"] == "calibrated" for r in tables["table_v"]) == 12
    assert tables["headline"] is None or "Hilbert" in tables["headline"]
    assert all(r["truth"]["position"]["mean"] > 0 for r in tables["table_v"])


# Hides every Vulkan driver from the loader, as on a machine with no GPU driver at all
# (tests/common/mod.rs `NO_DRIVER` does the same for the command).
NO_DRIVER = {"VK_DRIVER_FILES": "/nonexistent/no-driver.json",
             "VK_ICD_FILENAMES": "/nonexistent/no-driver.json"}


def test_training_and_prediction_without_a_gpu_driver(twin_data: dict, tmp_path: Path):
    """In a fresh interpreter that sees no Vulkan driver: `iastgcn.train` trains on the
    native CPU path and the Predictor loads and predicts on it."""
    model = tmp_path / "native.safetensors"
    script = f"""
import numpy as np
import iastgcn
trained = iastgcn.train({[str(r) for r in twin_data["recordings"]]!r},
                        {str(twin_data["calibration"])!r}, {str(model)!r},
                        config={str(ROOT / "assets/demo.toml")!r}, max_epochs=1)
assert trained["epochs"] == 1 and np.isfinite(trained["best_val"]), trained
p = iastgcn.Predictor({str(model)!r})
y = p.predict(np.zeros(p.window_shape, dtype=np.float32))
assert y.shape == (6,) and np.all(np.isfinite(y)), y
print(p.backend)
"""
    run = subprocess.run([sys.executable, "-c", script], env={**os.environ, **NO_DRIVER},
                         capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    assert run.stdout.strip() == "native"
    assert model.exists()


def test_a_failing_progress_callback_is_raised_after_the_call(twin_data: dict,
                                                              tmp_path: Path):
    def fail(event, text, position, total):
        raise KeyError("stop here")

    with pytest.raises(KeyError, match="stop here"):
        iastgcn.train(twin_data["recordings"], twin_data["calibration"],
                      tmp_path / "m.safetensors", config=ROOT / "assets/demo.toml",
                      max_epochs=1, progress=fail)


def test_library_errors_name_the_file(tmp_path: Path):
    with pytest.raises(iastgcn.Error, match="nowhere.csv"):
        iastgcn.calibrate(tmp_path / "nowhere.csv")
    with pytest.raises(iastgcn.Error, match="variant"):
        iastgcn.train([tmp_path / "a.csv"], tmp_path / "c.toml", tmp_path / "m.safetensors",
                      variant="resnet")
