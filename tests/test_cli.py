"""The command line without simulation: discovery, listings, and bad input (one line, exit code 2)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

import conflictbench

#: Every policy the command offers: the built-ins, any installed model plugin, and the test's demo plugin (which
#: may be installed already, as any third-party plugin may).
POLICIES = ", ".join(sorted({*conflictbench.plugins().policies(), "demo-wave"}))


def test_list_shows_builtins_and_the_pip_installed_third_party_plugin(cli):
    out = cli("list")
    assert out.returncode == 0, out.stderr
    lines = out.stdout.splitlines()
    assert any(line.split()[:3] == ["demo-wave", "conflictbench-demo", "0.3.1"] for line in lines)
    assert any(line.split()[:2] == ["noop", "conflictbench"] for line in lines)
    assert any(line.split()[:3] == ["demo_path_ratio", "conflictbench-demo", "0.3.1"] for line in lines)
    for family in ("instruction", "grounding", "spatial", "physical"):
        assert any(line.split()[:1] == [family] for line in lines)


def test_help_lists_the_verbs(cli):
    out = cli("--help")
    assert out.returncode == 0 and "conflictbench list" in out.stdout and "conflictbench report DIR" in out.stdout


@pytest.mark.parametrize(
    "args, message",
    [
        (["model=nope"], f"unknown model 'nope'; valid choices: {POLICIES}"),
        (["suite=physicl"], "unknown suite 'physicl'; valid choices: all, grounding, instruction, physical, spatial"),
        (["level=L5"], "unknown level 'L5'; valid choices: L1, L2, L3, L4, all"),
        (["prompt=p3"], "unknown prompt 'p3'; valid choices: both, p0, p1"),
        (["run=fast"], "unknown run 'fast'"),
        (["-m", "model=noop,nope"], "unknown model 'nope'"),
        (["run.metrics=[no_such_metric]"], "unknown metric 'no_such_metric'; valid choices:"),
        (["run.workers=0"], "run.workers must be an integer >= 1"),
        (["run.init_states=77"], "50 fixed initial states"),
        (["model=random", "model.sed=3"], "model.sed: random has no setting 'sed' (its settings: seed, scale)"),
        (["-m", "model=random,scripted", "model.scale=2"], "model.scale: scripted has no setting 'scale'"),
        (["model.sed=3"], "model.sed: subject has no setting 'sed'"),  # the default model
        (["suite.file=/no/such/suite.jsonl"], "suite file not found: /no/such/suite.jsonl"),
        (["report", "/no/such/dir"], "no such directory: /no/such/dir"),
        (["report"], "the following arguments are required: DIR"),
        (["list", "--bogus"], "unrecognized arguments: --bogus"),
        # a mistyped key gets one line naming the closest valid one, not Hydra's grammar, and Hydra's advice
        # (+key) does not make it silently run with the default
        (["run.init_state=2"], "run.init_state: the run has no option 'init_state' (did you mean init_states?)"),
        (["+run.init_state=2"], "run.init_state: the run has no option 'init_state' (did you mean init_states?)"),
        (["levl=L1"], "levl: no such option (did you mean level?)"),
        (["+levl=L1"], "levl: no such option (did you mean level?)"),
        (["suite.famlies=[spatial]"], "suite.famlies: the suite has no option 'famlies' (did you mean families?)"),
        (["model=random", "+model.extra=1"], "model.extra: random has no setting 'extra'"),
        (["reprot", "results"], "unknown command 'reprot' (did you mean report?)"),
    ],
)
def test_bad_input_is_one_clear_line_and_exit_code_2(cli, args, message):
    out = cli(*args)
    assert out.returncode == 2, (out.returncode, out.stdout, out.stderr)
    assert message in out.stderr + out.stdout
    assert "Traceback" not in out.stderr
    if args[0] not in ("report", "list"):  # a run's rejection: exactly one line, nothing of Hydra's
        lines = [line for line in out.stderr.splitlines() if line.strip()]
        assert len(lines) == 1 and lines[0].startswith("conflictbench: error:"), out.stderr


@pytest.mark.e2e  # costly (10-18 s): CI's marked lane plays it; the default selection stays under 10 min
def test_a_rejected_run_leaves_no_file_behind_and_keeps_an_existing_store(cli, tmp_path):
    kept = tmp_path / "kept"
    (kept / "episodes").mkdir(parents=True)
    (kept / "episodes" / "x.parquet").write_bytes(b"stored")
    (tmp_path / "mine").mkdir()  # a folder the user made beforehand stays, even empty
    for out_dir, sweep in ((tmp_path / "fresh", []), (tmp_path / "swept", ["-m"]), (kept, []), (tmp_path / "mine", [])):
        out = cli(*sweep, "suite.file=/no/such/suite.jsonl", f"run.out={out_dir}")
        assert out.returncode == 2 and "suite file not found" in out.stderr, out.stderr[-2000:]
    assert not (tmp_path / "fresh").exists() and not (tmp_path / "swept").exists()  # run.out was made for it
    assert sorted(str(p.relative_to(kept)) for p in kept.rglob("*")) == ["episodes", "episodes/x.parquet"]
    assert (tmp_path / "mine").is_dir() and not any((tmp_path / "mine").iterdir())


@pytest.mark.parametrize("run_dir", ["${run.out}", ".", "elsewhere"])
def test_tidying_after_a_rejection_never_touches_a_folder_hydra_was_pointed_at(cli, tmp_path, run_dir):
    """Only our own layout (<run.out>/hydra/<time>) is tidied: a hydra.run.dir of the user's keeps every file."""
    out_dir = tmp_path / "results"
    (out_dir / "episodes").mkdir(parents=True)
    (out_dir / "notes.txt").write_text("mine")
    (tmp_path / "mycode.py").write_text("mine")
    (tmp_path / "elsewhere").mkdir()
    (tmp_path / "elsewhere" / "old.log").write_text("mine")
    out = cli("model=noop", f"hydra.run.dir={run_dir}", "run.metrics=[bogus]", f"run.out={out_dir}")
    assert out.returncode == 2 and "unknown metric 'bogus'" in out.stderr, out.stderr[-2000:]
    for path in (
        out_dir / "episodes",
        out_dir / "notes.txt",
        tmp_path / "mycode.py",
        tmp_path / "elsewhere" / "old.log",
    ):
        assert path.exists(), path


def test_hydra_switches_may_follow_the_overrides(cli):
    out = cli("model=noop", "--version")  # Hydra wants its flags first; ours may stand anywhere
    assert out.returncode == 0 and "Hydra" in out.stdout + out.stderr, out.stderr[-2000:]


def test_config_help_shows_the_groups_and_hydra_help_hydras_flags(cli):
    config = cli("--config-help")
    assert config.returncode == 0 and "== Configuration groups ==" in config.stdout
    assert "model: " in config.stdout and "scripted" in config.stdout
    hydra = cli("--hydra-help")
    assert hydra.returncode == 0 and "== Flags ==" in hydra.stdout and "--multirun" in hydra.stdout


def test_report_on_a_directory_without_episodes_is_a_user_error(cli, tmp_path):
    (tmp_path / "empty").mkdir()
    out = cli("report", str(tmp_path / "empty"))
    assert out.returncode == 2 and "holds no stored episodes" in out.stderr


@pytest.mark.sim  # the rules read LIBERO's base tasks
def test_a_suite_file_that_breaks_the_rules_or_holds_nothing_is_not_played(cli, tmp_path):
    from conflictbench.tasks.suite.file import shipped_suite_path

    rows = [json.loads(line) for line in shipped_suite_path().read_text().splitlines()[1:4]]
    rows[1]["instruction"] = rows[1]["base_instruction"]  # `suite validate` rejects it
    bad, empty = tmp_path / "bad.jsonl", tmp_path / "empty.jsonl"
    bad.write_text("\n".join(json.dumps(row) for row in rows) + "\n")
    empty.write_text("")
    for path, message in (
        (bad, f"1 of 3 cases break the suite's rules (e.g. {rows[1]['case_id']}: the instruction equals the base"),
        (empty, "empty.jsonl holds no cases"),
    ):
        out = cli(f"suite.file={path}", f"run.out={tmp_path / 'results'}")
        errors = [line for line in out.stderr.splitlines() if line.startswith("conflictbench: error:")]
        assert out.returncode == 2 and len(errors) == 1 and message in errors[0], out.stderr[-2000:]
        assert "Traceback" not in out.stderr and not (tmp_path / "results" / "episodes").exists()


def test_a_tampered_suite_file_names_the_line_and_field(cli, tmp_path):
    from conflictbench.tasks.suite.file import shipped_suite_path

    lines = shipped_suite_path().read_text().splitlines()
    lines[3] = lines[3].replace('"level": "L', '"level": "X')
    bad = tmp_path / "bad.jsonl"
    bad.write_text("\n".join(lines) + "\n")
    out = cli(f"suite.file={bad}")
    assert out.returncode == 2 and "line 4, field 'level'" in out.stderr and "Traceback" not in out.stderr


def test_a_symlinked_store_folder_is_never_tidied_away(cli, tmp_path):
    target = tmp_path / "scratch"
    target.mkdir()
    (tmp_path / "results").symlink_to(target)
    out = cli("model=noop", "run.metrics=[bogus]", "run.out=results")
    assert out.returncode == 2 and "unknown metric" in out.stderr
    assert (tmp_path / "results").is_symlink() and target.is_dir()


@pytest.mark.parametrize(
    "argv",
    [
        ["-m", "model=choice(random)", "model.seed=3"],  # a sweep function: Hydra checks
        ["--config-name", "other", "model.seed=3"],  # another config's default model
        ["model=random", "model.seed=3"],
    ],
)
def test_model_field_check_leaves_what_it_cannot_know_to_hydra(argv):
    from conflictbench.cli.run import check_model_fields

    check_model_fields(argv, conflictbench.plugins())  # no UserError


@pytest.mark.parametrize(
    "argv, expected",
    [
        (["model=noop", "--cfg", "job", "prompt=p1"], ["--cfg", "job", "model=noop", "prompt=p1"]),
        (["model=noop", "-r", "prompt=p1"], ["-r", "model=noop", "prompt=p1"]),
        (["run.out=x", "-m", "model=a,b"], ["-m", "run.out=x", "model=a,b"]),
        (["model=noop", "--info", "prompt=p1"], ["--info", "model=noop", "prompt=p1"]),
        (["model=noop", "--info", "defaults"], ["--info", "defaults", "model=noop"]),
        (["--config-help"], ["--help"]),
        (["--hydra-help"], ["--hydra-help"]),
    ],
)
def test_hydras_flags_go_first_with_their_values(argv, expected):
    from conflictbench.cli.run import hydra_argv

    assert hydra_argv(argv) == expected


def test_a_model_of_this_project_whose_plugin_is_missing_names_the_command_that_installs_it():
    from conflictbench.cli.overrides import check_group_overrides
    from conflictbench.core import Plugins, UserError

    without_plugins = Plugins(conflictbench.BUILTIN_PLUGINS, entry_points=False)
    expected = (
        r"^model=pi0-fast comes with the pi0 model plugin, which is not installed here: scripts/setup.sh --models pi0 "
    )
    with pytest.raises(UserError, match=expected):
        check_group_overrides(["model=pi0-fast"], without_plugins)
    with pytest.raises(UserError, match=r"^unknown model 'nope'; valid choices: "):
        check_group_overrides(["model=nope"], without_plugins)


def test_each_plugin_folder_declares_the_policies_its_plugin_registers():
    """The "which command installs it" hint reads each ``plugins/<folder>``'s declared policies (no list of the
    plugins outside their folders): every folder declares them, no policy twice, and an installed plugin registers
    exactly those."""
    import tomllib

    from conflictbench.cli.overrides import checkout_plugins, project_plugins

    plugins = Path(__file__).parents[1] / "plugins"
    folders = {p.name: p for p in plugins.iterdir() if (p / "pyproject.toml").exists()}
    declared = {folder: table["policies"] for folder, table in checkout_plugins().items()}
    assert set(declared) == set(folders) and all(declared.values())
    assert len(project_plugins()) == sum(len(policies) for policies in declared.values())  # no policy twice
    names = {f: tomllib.loads((p / "pyproject.toml").read_text())["project"]["name"] for f, p in folders.items()}
    distributions = {name: folder for folder, name in names.items()}
    registered: dict[str, set[str]] = {}
    for name, spec in conflictbench.plugins().policies().items():
        if spec.plugin in distributions:
            registered.setdefault(distributions[spec.plugin], set()).add(name)
    if not registered:
        pytest.skip("no model plugin of this project is installed here")
    assert registered == {folder: set(declared[folder]) for folder in registered}


@pytest.mark.parametrize(
    "argv",
    [
        ["hydra.run.dir=x", "hydra.job.chdir=true", "+hydra/launcher=ray", "hydra.sweeper.params.x=1"],
        ["-m", "run.init_states=1,2", "level=L1,L2", "model.seed=3,4"],
        ["--config-help"],
        ["~run.tasks", "run.out=x", "suite.file=x.jsonl", "prompt.conditions=[p1]", "level.levels=[L1]"],
        ["--config-dir", "mine", "+experiment=fast", "extra.key=1"],  # another config folder: Hydra checks
    ],
)
def test_hydras_own_syntax_passes_the_key_check(argv):
    from conflictbench.cli.overrides import check_known_keys

    check_known_keys(argv)  # no UserError


def test_every_verb_and_only_a_verb_is_taken_for_one():
    from conflictbench.cli import VERBS
    from conflictbench.cli.overrides import check_verb

    for verb in VERBS:
        check_verb([verb, "x"], VERBS)
    for argv in (["model=noop"], ["-m", "x"], ["--config-help"], ["~run.tasks"], []):
        check_verb(argv, VERBS)
    with pytest.raises(conflictbench.core.UserError, match=r"unknown command 'lsit' \(did you mean list\?\)"):
        check_verb(["lsit"], VERBS)
    with pytest.raises(conflictbench.core.UserError, match="unknown command 'zzz'; commands: "):
        check_verb(["zzz"], VERBS)
