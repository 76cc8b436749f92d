"""``conflictbench-serve`` where torch is missing: in a model environment a backend of numpy alone is served without
it; the simulator's Python (it holds conflictbench) or a backend whose import fails on torch is one line naming the
model environment's Python; another missing library in a model environment, one line saying that it lacks it."""

from __future__ import annotations

import importlib.util
import signal
import sys

import numpy as np
import pytest

from conflictbench_serving import command

TORCH = importlib.util.find_spec("torch") is not None
without_torch = pytest.mark.skipif(TORCH, reason="what a Python without torch does")


def in_a_model_environment(monkeypatch) -> None:
    monkeypatch.setitem(sys.modules, "conflictbench", None)  # not importable, as in a model environment


@pytest.fixture(autouse=True)
def sigterm_kept():
    """serve_command sets SIGTERM's handler (the command's process is its own): put back pytest's."""
    handler = signal.getsignal(signal.SIGTERM)
    yield
    signal.signal(signal.SIGTERM, handler)


class NumpyBackend:
    def __init__(self, checkpoint, device: str) -> None:
        self.device, self.metadata = device, {"policy_type": "toy"}

    def infer_batch(self, rows):
        return [np.asarray(row) * 2 for row in rows]


def load_torch_backend(checkpoint, device: str):
    import torch  # noqa: F401  (what is missing in a Python without it)


def load_backend_of_a_missing_library(checkpoint, device: str):
    import conflictbench_no_such_library  # noqa: F401


def serve(backend, tmp_path, *extra: str) -> tuple[int, dict]:
    """``cb-test serve --policy toy --checkpoint TMP`` with ``backend``: the exit code and what the server got."""
    served: dict = {}

    def server(loaded, host, port, max_batch, on_ready):
        served["backend"] = loaded
        on_ready(host, 4321)

    model = command.ServedModel(
        environment="toy", policies=("toy",), protocol="a test protocol", check=lambda *args: None,
        backend=backend, server=server,
    )  # fmt: skip
    argv = ["serve", "--policy", "toy", "--checkpoint", str(tmp_path), *extra]
    return command.serve_command(
        "cb-test", model, command.build_plugin_parser("cb-test", model).parse_args(argv)
    ), served


@without_torch
def test_a_backend_of_numpy_alone_is_served_without_torch_in_a_model_environment(tmp_path, capsys, monkeypatch):
    in_a_model_environment(monkeypatch)
    code, served = serve(NumpyBackend, tmp_path)
    assert code == 0 and served["backend"].device == "cpu"
    assert capsys.readouterr().err == f"cb-test: serving toy from {tmp_path} on ws://127.0.0.1:4321\n"
    assert "model_stack" in served["backend"].metadata  # what a run counts in its identity, torch or not


@without_torch
@pytest.mark.parametrize("conflictbench_here", [True, False], ids=["simulators-python", "a-model-environment"])
@pytest.mark.parametrize(
    "backend, extra", [(load_torch_backend, []), (NumpyBackend, ["--device", "cuda"])], ids=["imports-torch", "cuda"]
)
def test_where_torch_is_missing_one_line_names_the_model_environments_python(
    tmp_path, capsys, monkeypatch, backend, extra, conflictbench_here
):
    if not conflictbench_here:
        in_a_model_environment(monkeypatch)
    assert serve(backend, tmp_path, *extra)[0] == 2
    assert capsys.readouterr().err == (
        "cb-test: cannot import the model stack (No module named 'torch'): run this with the model environment's "
        "python (scripts/setup.sh --models toy builds it), not the simulator's\n"
    )


def test_another_missing_library_is_the_wrong_python_in_the_simulators_and_a_gap_in_a_model_environment(
    tmp_path, capsys, monkeypatch
):
    if importlib.util.find_spec("conflictbench") is not None:  # this Python is the simulator's
        assert serve(load_backend_of_a_missing_library, tmp_path)[0] == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "run this with the model environment's python" in err
    in_a_model_environment(monkeypatch)
    assert serve(load_backend_of_a_missing_library, tmp_path)[0] == 2
    assert capsys.readouterr().err == (
        "cb-test: cannot import the model stack (No module named 'conflictbench_no_such_library'): "
        "scripts/setup.sh --models toy builds it\n"
    )
