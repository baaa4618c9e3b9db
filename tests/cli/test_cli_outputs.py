"""The shared output-path check (``magtune_core.cli.common.check_output``) and the commands that
regenerate tracked files: they refuse, before any work, to overwrite without ``--force``, and
find their default inputs from any working directory."""
from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest

from magtune_core.base.ament import ROOT
from magtune_core.base.errors import ConfigError
from magtune_core.cli import main as cli_main
from magtune_core.cli.common import check_output, check_outputs


def test_check_output_new_file_in_new_directory(tmp_path):
    out = tmp_path / "a" / "b" / "gains.yaml"
    assert check_output(out) == out
    assert not (tmp_path / "a").exists()  # the check creates nothing


def test_check_output_refuses_existing_file_without_force(tmp_path):
    out = tmp_path / "g.yaml"
    out.write_text("keep me\n")
    with pytest.raises(ConfigError, match=r"exists; pass --force to overwrite it, or --out to write elsewhere"):
        check_output(out)
    assert check_output(out, force=True) == out
    assert out.read_text() == "keep me\n"


def test_check_output_rejects_directory_and_file_ancestor(tmp_path):
    with pytest.raises(ConfigError, match="is a directory"):
        check_output(tmp_path)
    blocker = tmp_path / "plain_file"
    blocker.write_text("")
    with pytest.raises(ConfigError, match="is not a directory"):
        check_output(blocker / "sub" / "x.yaml")
    with pytest.raises(ConfigError, match="exists and is not a directory"):
        check_output(blocker, directory=True, option="--log-dir")


def test_check_output_unwritable_location():
    # /proc refuses new files even to root, where os.access would say yes: the probe catches it.
    with pytest.raises(ConfigError, match=r"cannot write in directory /proc.*--results"):
        check_output("/proc/magtune_results.npz", option="--results")


def test_check_outputs_names_existing_files(tmp_path):
    (tmp_path / "sampling.md").write_text("")
    with pytest.raises(ConfigError, match=r"already holds sampling.md; pass --force.*--out-dir"):
        check_outputs(tmp_path, ("sampling.md", "sampling.png"), option="--out-dir")
    assert check_outputs(tmp_path, ("sampling.md", "sampling.png"), force=True) == [
        tmp_path / "sampling.md", tmp_path / "sampling.png"]


def _git_status(path: Path) -> str:
    r = subprocess.run(["git", "-C", str(ROOT), "status", "--porcelain", "--", str(path)],
                       capture_output=True, text=True)
    return r.stdout if r.returncode == 0 else "<no git>"


def test_tune_refuses_to_overwrite_shipped_gains(capsys):
    """``magtune tune --sigma 60 --samples 50`` leaves the shipped gains alone: exit 2 at once."""
    shipped = ROOT / "config" / "gains" / "sigma_60.yaml"
    before, status = shipped.read_bytes(), _git_status(shipped)
    t0 = time.perf_counter()
    assert cli_main(["tune", "--sigma", "60", "--method", "paper", "--samples", "50"]) == 2
    assert time.perf_counter() - t0 < 5.0  # refused before the tuner started (a tune takes ~20 s)
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "sigma_60.yaml: exists; pass --force" in err, err
    assert shipped.read_bytes() == before and _git_status(shipped) == status


@pytest.mark.parametrize("argv, option, method", [
    (["--samples", "50"], "--samples", "paper"),  # the default method is cma: --samples would be ignored
    (["--method", "paper", "--max-evals", "100"], "--max-evals", "cma"),
    (["--method", "paper", "--gain-margin", "3"], "--gain-margin", "cma"),  # the paper's problem is unconstrained
])
def test_tune_refuses_options_of_the_other_method(argv, option, method, capsys):
    """An option the chosen method does not read is refused (one line, exit 2), not silently ignored."""
    assert cli_main(["tune", "--sigma", "60", "--out", "/nonexistent-dir/x.yaml", *argv]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and option in err and f"--method {method}" in err, err


@pytest.mark.parametrize("argv, option", [
    (["tune", "--sigma", "60", "--gain-margin", "0.5"], "--gain-margin"),
    (["tune", "--sigma", "60", "--gain-margin", "nan"], "--gain-margin"),
    (["tune", "--sigma", "60", "--ts", "0"], "--ts"),
    # the spec owns the sample periods: --ts beside --spec was silently replaced by the spec's ts_min
    (["tune", "--sigma", "60", "--spec", "config/design.yaml", "--ts", "5"], "--ts: the design spec"),
    (["front", "--sigmas", "60", "--gain-margin", "inf"], "--gain-margin"),
])
def test_hold_constraint_options_are_checked_first(argv, option, tmp_path, capsys):
    """--ts / --gain-margin out of range: one line naming the option, exit 2, before any work."""
    assert cli_main([*argv, "--out" if argv[0] == "tune" else "--out-dir", str(tmp_path / "x")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and option in err, err


def test_tune_refuses_a_margin_no_start_scaling_meets(tmp_path, capsys):
    """A margin the start gain cannot meet even scaled down 100x: one line naming the option, exit 2.
    (The LQ gain's own margin at 1 s is ~77: 40 x LQ has 1.93; 1e5 would need it scaled below
    ~8e-4, and feasible_start stops at 0.95^90 ~ 0.01.)"""
    assert cli_main(["tune", "--sigma", "60", "--gain-margin", "1e5", "--out", str(tmp_path / "g.yaml"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "--gain-margin" in err and "meets the hold constraint" in err, err
    assert not (tmp_path / "g.yaml").exists()


@pytest.mark.parametrize("argv, name", [
    (["table1"], "docs/table1.md"),
    (["fit-field"], "config/field_model.yaml"),
    (["sampling"], "docs"),
])
def test_regenerating_commands_refuse_tracked_defaults(argv, name, capsys):
    target = ROOT / name
    assert cli_main(argv) == 2
    err = capsys.readouterr().err
    assert "--force" in err and str(target) in err, err


def test_defaults_found_from_any_directory(tmp_path):
    """``analyze`` run from a foreign directory reads config/spacecraft.yaml of the repository."""
    gains = ROOT / "config" / "gains" / "sigma_60.yaml"
    r = subprocess.run([sys.executable, "-m", "magtune_core", "analyze", str(gains), "--json", "--steps", "16"],
                       cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert '"rho"' in r.stdout


def test_version_and_plain_help(capsys):
    with pytest.raises(SystemExit) as exc:
        cli_main(["--version"])
    assert exc.value.code == 0
    from magtune_core import __version__
    assert capsys.readouterr().out.strip() == f"magtune {__version__}"


def _parsers():
    import argparse

    from magtune_core.cli import build_parser

    todo = [("magtune", build_parser())]
    while todo:
        name, p = todo.pop()
        yield name, p
        for a in p._actions:
            if isinstance(a, argparse._SubParsersAction):
                todo += [(f"{name} {n}", sp) for n, sp in a.choices.items()]


def test_every_option_has_plain_help():
    """Every option and positional argument of every subcommand has help; help text and
    descriptions carry no reStructuredText markup (double backticks, :mod:, :func: roles)."""
    import argparse

    missing, markup = [], []
    for name, p in _parsers():
        for a in p._actions:
            if isinstance(a, (argparse._HelpAction, argparse._SubParsersAction)):
                continue
            if not a.help:
                missing.append(f"{name} {'/'.join(a.option_strings) or a.dest}")
        text = p.format_help()
        if "``" in text or ":mod:" in text or ":func:" in text or "`" in text:
            markup.append(name)
    assert not missing, missing
    assert not markup, markup


def test_sil_progress_follows_the_simulator_log(tmp_path):
    """The progress of ``magtune sil`` comes from the simulator's own ``step k/n`` log lines:
    whole lines only, each step once, and (n, n) at the end."""
    from magtune_core.ros.sil import LogProgress

    log = tmp_path / "simulator.log"
    seen = []
    watch = LogProgress(log, lambda k, n: seen.append((k, n)))
    watch.poll()  # no file yet: nothing, no error
    log.write_bytes(b"[INFO] [simulator]: step 10/100: 0.1 ms/step\n[INFO] [simulator]: step 2")
    watch.poll()
    with open(log, "ab") as fh:
        fh.write(b"0/100: 0.1 ms/step\nother line\n")
    watch.poll()
    watch.poll()
    watch.finish()
    assert seen == [(10, 100), (20, 100), (100, 100)]


@pytest.mark.parametrize("gains, msg", [
    (["sat 1=x.yaml"], "/sat 1: not a valid ROS namespace"),
    (["sat1=a.yaml", "/sat1/=b.yaml"], "namespace /sat1 given twice"),
])
def test_sil_satellite_arguments_checked_first(gains, msg, capsys):
    assert cli_main(["sil", "--gains", *gains, "--orbits", "0.01"]) == 2
    err = capsys.readouterr().err
    assert msg in err and err.count("\n") == 1, err


@pytest.mark.slow
def test_table1_force_failing_write_keeps_old_table_and_notes(tmp_path):
    """Why: ``table1 --force`` wrote in place; a failed write (here a 1 kB file-size limit: the
    table is about 2 kB) lost the old table and the notes kept below its marker."""
    import resource

    from magtune_core.cli.table1 import TABLE1_MARKER

    out = tmp_path / "table1.md"
    out.write_text(f"# old table\n\n{TABLE1_MARKER}\nmy notes, kept by hand\n")
    before = out.read_bytes()

    def limit():
        resource.setrlimit(resource.RLIMIT_FSIZE, (1024, resource.RLIM_INFINITY))

    r = subprocess.run([sys.executable, "-m", "magtune_core", "table1", "--force", "--out", str(out)],
                       capture_output=True, text=True, preexec_fn=limit, timeout=300)
    assert r.returncode != 0 and "| sigma |" in r.stdout, (r.returncode, r.stderr[-500:])  # failed at the write
    assert out.read_bytes() == before and sorted(p.name for p in tmp_path.iterdir()) == ["table1.md"]
