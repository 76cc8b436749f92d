"""What a rejected command takes back: Hydra's record of the job, and a ``run.out`` folder made for it."""

from __future__ import annotations

import contextlib
import os
import re
from collections.abc import Sequence
from importlib import resources
from pathlib import Path

from omegaconf import OmegaConf


def out_not_yet_made(argv: Sequence[str]) -> Path | None:
    """The ``run.out`` this command line names (or the default), absolute, if it does not exist yet: a rejected
    command takes it back. None where the line sweeps it or computes it (then it is left alone)."""
    values = [a.partition("=")[2] for a in argv if a.partition("=")[0].lstrip("+") == "run.out"]
    out = (
        values[-1]
        if values
        else str(OmegaConf.load(str(resources.files("conflictbench.conf") / "run/default.yaml")).out)
    )
    if not out or any(ch in out for ch in ",${}()[]*"):
        return None
    path = Path(os.path.abspath(out))
    return None if os.path.lexists(path) else path


#: The folders our config has Hydra make under ``<run.out>/hydra/``: a run's, a sweep's and a sweep job's.
RUN_FOLDER = re.compile(r"\d{4}-\d{2}-\d{2}_\d{2}-\d{2}-\d{2}(-\d{6})?")  # (older versions: to the second)
SWEEP_FOLDER = re.compile(r"multirun_" + RUN_FOLDER.pattern)


def remove_hydra_output(folder: Path, out: Path, job_name: str = "conflictbench") -> None:
    """Take back what Hydra wrote for a rejected job: its record files and log, and the folders that leaves
    empty, below ``<run.out>/hydra``. Only in our own layout (a ``hydra.run.dir`` or ``hydra.sweep.dir`` set
    elsewhere is left alone), only the files Hydra writes, only empty folders: nothing of the user's goes."""
    try:
        folder, out = Path(os.path.abspath(folder)), Path(os.path.abspath(out))
        hydra_root = out / "hydra"
        sweep = folder.parent if SWEEP_FOLDER.fullmatch(folder.parent.name) and folder.name.isdigit() else None
        if sweep is not None:
            run_folder_ok = sweep.parent == hydra_root
        else:
            run_folder_ok = folder.parent == hydra_root and RUN_FOLDER.fullmatch(folder.name) is not None
        if not run_folder_ok or hydra_root.is_symlink() or out.is_symlink():
            return
        for name in ("config.yaml", "hydra.yaml", "overrides.yaml"):
            (folder / ".hydra" / name).unlink(missing_ok=True)
        (folder / f"{job_name}.log").unlink(missing_ok=True)
        for empty in (folder / ".hydra", folder):
            with contextlib.suppress(OSError):
                empty.rmdir()  # only where empty
        if sweep is not None:  # a rejected sweep job ends the sweep: its record goes where no job kept a folder
            if [p.name for p in sweep.iterdir()] == ["multirun.yaml"]:
                (sweep / "multirun.yaml").unlink()
            with contextlib.suppress(OSError):
                sweep.rmdir()
        with contextlib.suppress(OSError):
            hydra_root.rmdir()  # run.out itself stays
    except OSError:
        pass  # tidying up after a rejection must never hide its one line
