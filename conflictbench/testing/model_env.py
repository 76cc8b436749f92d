"""A model plugin's model environment in its tests: where it is, how its processes run, tiny checkpoints built once.

::

    GR00T = ModelEnvironment("gr00t", Path(__file__).parent, extra=lambda checkpoint: {"HF_HOME": ...})
    needs_model_env = GR00T.needs                       # marks model_env, skips where the environment is missing
    tiny_checkpoint = GR00T.checkpoint_fixture("tiny_groot.py", name="tiny_groot_checkpoint")

Every process gets what the model stacks need to run here, offline and repeatably: no hub, no bfloat16 kernel
beyond AVX512 (it kills some CPUs' VMs), one CPU thread, and the plugin's tests folder on ``PYTHONPATH`` (their
stand-ins and builders); ``extra(checkpoint)`` adds a plugin's own (its checkpoint's hub cache, a checkout).
"""

from __future__ import annotations

import os
import subprocess
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING

from ..hosting import MODEL_PROCESS_ENV, model_environment

if TYPE_CHECKING:
    import pytest

#: What every model-environment process in the tests gets (before a plugin's ``extra``).
BASE_ENV: Mapping[str, str] = {
    **MODEL_PROCESS_ENV,
    "HF_HUB_OFFLINE": "1",
    "TRANSFORMERS_OFFLINE": "1",
    "OMP_NUM_THREADS": "1",
    "MKL_NUM_THREADS": "1",
    "TOKENIZERS_PARALLELISM": "false",
}


class ModelEnvironment:
    """The model environment ``scripts/setup.sh --models NAME`` builds, as a plugin's tests use it."""

    def __init__(self, name: str, tests: Path, extra: Callable[[Path | None], Mapping[str, str]] | None = None):
        self.name, self.tests = name, Path(tests).resolve()
        self.python = model_environment(name) / "bin" / "python"
        self.reason = f"no {name} model environment at {self.python} (scripts/setup.sh --models {name})"
        self._extra = extra

    @property
    def missing(self) -> bool:
        return not self.python.exists()

    def needs(self, test):
        """Marks a test that runs model-environment processes, and skips it where the environment is missing."""
        import pytest  # here, not at the top: importing these helpers (and what imports them) never needs pytest

        return pytest.mark.model_env(pytest.mark.skipif(self.missing, reason=self.reason)(test))

    def env(self, checkpoint: Path | None = None) -> dict[str, str]:
        """``os.environ`` plus what a process loading ``checkpoint`` needs."""
        extra = dict(self._extra(checkpoint)) if self._extra else {}
        return {**os.environ, **BASE_ENV, "PYTHONPATH": str(self.tests), **extra}

    def use(self, monkeypatch: pytest.MonkeyPatch, checkpoint: Path | None = None) -> None:
        """This process's environment set as :meth:`env`'s, so that a server it starts gets the same."""
        for key, value in self.env(checkpoint).items():
            monkeypatch.setenv(key, value)

    def run(
        self,
        argv: list[str],
        checkpoint: Path | None = None,
        timeout: float = 600,
        check: bool = True,
        env: Mapping[str, str] | None = None,
    ) -> subprocess.CompletedProcess:
        """``python *argv`` in the model environment (its output captured); fails the test on an error exit
        unless ``check`` is false."""
        done = subprocess.run([str(self.python), *argv], env=dict(env or self.env(checkpoint)), capture_output=True,
                              text=True, timeout=timeout)  # fmt: skip
        if check and done.returncode != 0:
            import pytest

            pytest.fail(f"{argv[0]} exited {done.returncode}:\n{done.stderr[-3000:]}", pytrace=False)
        return done

    def checkpoint_fixture(self, builder: str, name: str = "tiny_checkpoint"):
        """A session fixture ``name``: the tiny checkpoint ``python builder FOLDER`` (in the tests folder) builds,
        once per session; skips where the environment is missing."""
        import pytest

        @pytest.fixture(scope="session", name=name)
        def fixture(tmp_path_factory) -> Path:
            if self.missing:
                pytest.skip(self.reason)
            folder = tmp_path_factory.mktemp(f"{name}-{self.name}") / "checkpoint"
            self.run([str(self.tests / builder), str(folder)], folder)
            return folder

        return fixture
