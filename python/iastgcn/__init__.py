"""iastgcn: predict a robot's pose residual errors so that its controller can compensate them.

The engine is Rust (https://pyo3.rs binding); this package is a thin layer over it, and
every number it returns comes from the same library calls as the ``iastgcn`` command.

In a control loop::

    import numpy as np, iastgcn

    predictor = iastgcn.Predictor("model.safetensors", dt=0.02)  # load once
    for frame in sensor_frames():          # one value per node, in predictor.nodes order
        predictor.push(frame)              # NaN: no new sample this tick
        residual = predictor.predict_latest()   # None until T ticks are in
        if residual is not None:
            command_pose -= residual       # dx, dy, dz µm; rx, ry, rz mdeg

In a notebook, the demo's steps one by one (each takes ``progress=``, a callable such
as :func:`print_progress`)::

    data = iastgcn.record_data("run", minutes=2, progress=iastgcn.print_progress)
    iastgcn.train(data["recordings"], data["calibration"], "run/iastgcn.safetensors",
                  config="assets/demo.toml", progress=iastgcn.print_progress)
    tables = iastgcn.evaluate(["run/iastgcn.safetensors"], data["recordings"],
                              data["calibration"], "run/report")

Every failure raises :class:`iastgcn.Error` with the engine's message. docs/embedding.md
in the repository has the whole guide.
"""

from ._native import (
    Error,
    Predictor,
    __version__,
    adapt,
    calibrate,
    calibrate_arm,
    evaluate,
    record_data,
    refine,
    train,
)

__all__ = [
    "Error",
    "Predictor",
    "__version__",
    "adapt",
    "calibrate",
    "calibrate_arm",
    "evaluate",
    "print_progress",
    "record_data",
    "refine",
    "train",
]


def print_progress(event: str, text: str, position: int, total: int) -> None:
    """A progress callback that prints: notes as lines, tasks as one updating line.

    Pass it as ``progress=iastgcn.print_progress`` to the long calls. A callback gets
    ``(event, text, position, total)`` with event ``"begin"`` (a task of ``total``
    units named ``text``), ``"update"`` (``position`` units done; ``text`` says how it
    stands), ``"end"`` or ``"note"`` (a line for the user). An exception raised by a
    callback stops the calls to it and is raised when the library call returns.
    """
    if event == "note":
        print(text, flush=True)
    elif event == "begin":
        print_progress.task = (text, total)  # type: ignore[attr-defined]
    elif event == "update":
        name, length = getattr(print_progress, "task", ("", 0))
        of = f"/{length}" if length else ""
        print(f"\r{name}: {position}{of} {text}".ljust(79)[:79], end="", flush=True)
    elif event == "end":
        print(flush=True)
