"""The openvla model environment in tests: a tiny stand-in checkpoint built once per session (``tiny_openvla.py``);
every process gets a modules cache of the session's own for the checkpoint's code (``trust_remote_code``)."""

from __future__ import annotations

from pathlib import Path

from conflictbench.testing import ModelEnvironment

TESTS = Path(__file__).resolve().parent
OPENVLA = ModelEnvironment(
    "openvla", TESTS, extra=lambda checkpoint: {"HF_MODULES_CACHE": str(checkpoint.parent / "hf_modules")}
)
needs_model_env, model_env, run_in_model_env = OPENVLA.needs, OPENVLA.env, OPENVLA.run
MODEL_PYTHON = OPENVLA.python
tiny_checkpoint = OPENVLA.checkpoint_fixture("tiny_openvla.py")


def start_server(checkpoint: Path, log_dir: Path, max_batch: int = 1):
    """``conflictbench-serve openvla`` for ``checkpoint`` on a free port, answering; ``(server, port)``."""
    from conflictbench import ServerProcess, free_port

    port = free_port()
    argv = [str(MODEL_PYTHON), "-m", "conflictbench_serving", "openvla", "--checkpoint",
            str(checkpoint), "--port", str(port), "--max-batch", str(max_batch)]  # fmt: skip
    server = ServerProcess(argv, name="openvla", health_url=f"http://127.0.0.1:{port}/healthz",
                           env=model_env(checkpoint), startup_timeout_s=300, log_dir=log_dir)  # fmt: skip
    return server.start(), port
