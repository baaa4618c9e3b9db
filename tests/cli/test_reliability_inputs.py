"""Ground tools against concurrent writers and hostile inputs (issue 45): one writer per output, bag
files that are regular files, bounded input files and numbers, defaults independent of the working
directory. Each test failed (or hung, or took half a minute) before the change."""
from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from magtune_core import bags as bag
from magtune_core.bags.decode import Decoder
from magtune_core.bags.playback import ReplayOptions, check_numbers
from magtune_core.base.ament import ROOT
from magtune_core.base.atomic import LOCK_NAME, output_lock
from magtune_core.base.errors import ConfigError
from magtune_core.cli import main as cli_main
from magtune_core.cli.sil import check_domain_id

GAINS = str(ROOT / "config" / "gains" / "sigma_60.yaml")
CAMPAIGN = str(ROOT / "config" / "campaigns" / "example.yaml")
HOLDER = "magtune other"


def _tiny_bag(root: Path, name: str = "tiny") -> Path:
    """A complete bag of five /clock messages (0..4 s)."""
    d = Decoder()
    T = d.types()
    w = bag.BagWriter(root / name)
    w.add_topic("/clock", "rosgraph_msgs/msg/Clock")
    for i in range(5):
        msg = T["rosgraph_msgs/msg/Clock"](clock=T["builtin_interfaces/msg/Time"](sec=i, nanosec=0))
        w.write("/clock", d.encode(msg, "rosgraph_msgs/msg/Clock"), i * 1_000_000_000)
    w.close()
    return root / name


def _one_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert "Traceback" not in err
    return lines[0]


@pytest.fixture
def watchdog():
    """Fail (instead of hanging the suite) if a command blocks: a FIFO opened for reading waits for a writer."""
    def expire(signum, frame):  # noqa: ARG001
        raise TimeoutError("the command blocked (a FIFO or a device was opened for reading)")
    old = signal.signal(signal.SIGALRM, expire)
    signal.alarm(30)
    yield
    signal.alarm(0)
    signal.signal(signal.SIGALRM, old)


# ---------------------------------------------------------------- one writer per output

def _writers(tmp_path: Path) -> dict:
    """command -> (argv, the output it locks, is it a directory, the option naming it)."""
    tiny = _tiny_bag(tmp_path / "in")
    d, f = tmp_path / "out", tmp_path / "out.yaml"
    (tmp_path / "camp").mkdir()
    (tmp_path / "camp" / "runs.parquet").write_bytes(b"")
    (tmp_path / "camp" / "campaign.json").write_text("{}")
    return {
        "campaign": (["campaign", CAMPAIGN, "--runs", "1", "--scheduler", "synchronous", "--no-progress",
                      "--out", str(d)], d, True, "--out"),
        "verify": (["verify", GAINS, "--runs", "1", "--scheduler", "synchronous", "--no-progress", "--out", str(d)],
                   d, True, "--out"),
        "sampling": (["sampling", "--sigmas", "60", "--ts", "1", "--orbits", "0.01", "--workers", "1",
                      "--out-dir", str(d)], d, True, "--out-dir"),
        "report": (["report", str(tiny), "--out", str(d)], d, True, "--out"),
        "tune": (["tune", "--sigma", "60", "--max-evals", "16", "--verify-runs", "0", "--quiet", "--out", str(f)],
                 f, False, "--out"),
        "campaign-report": (["campaign-report", str(tmp_path / "camp")], tmp_path / "camp", True, "DIR"),
        "table1": (["table1", "--out", str(tmp_path / "table1.md")], tmp_path / "table1.md", False, "--out"),
        "fit-field": (["fit-field", "--days", "0.1", "--step", "120", "--out", str(f)], f, False, "--out"),
        "front": (["front", "--sigmas", "60", "--max-evals", "16", "--workers", "1", "--out-dir", str(d)],
                  d, True, "--out-dir"),
        "bag recover": (["bag", "recover", str(tiny), "-o", str(d)], d, True, "--output"),
        "export": (["export", GAINS, "--steps", "5", "--out", str(d)], d, True, "--out"),
    }


@pytest.mark.parametrize("command", ["campaign", "verify", "sampling", "report", "tune", "campaign-report", "table1",
                                     "fit-field", "front", "bag recover", "export"])
def test_second_writer_of_an_output_gets_one_line_and_exit_2(tmp_path, capsys, command):
    argv, out, directory, option = _writers(tmp_path)[command]
    capsys.readouterr()
    with output_lock(out, HOLDER, directory=directory):
        before = sorted(os.listdir(out if directory else out.parent))
        assert cli_main(argv) == 2
        line = _one_line(capsys.readouterr().err)
        assert line == (f"magtune {command}: error: {out}: is being written by {HOLDER} (pid {os.getpid()}); "
                        f"wait until it ends, or choose another {option}")
        assert sorted(os.listdir(out if directory else out.parent)) == before  # nothing was started


def test_second_writer_in_another_process_and_the_lock_released_at_the_end(tmp_path, capsys):
    """Two processes: the second (a real ``magtune verify``) gets one line and exit 2; once the first
    ends, a later run of the same output works and leaves no lock file."""
    tiny = _tiny_bag(tmp_path / "in")
    out = tmp_path / "rec"
    with output_lock(out, "magtune bag recover"):
        r = subprocess.run([sys.executable, "-m", "magtune_core", "verify", GAINS, "--out", str(out)],
                           capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert r.returncode == 2
    assert _one_line(r.stderr) == (f"magtune verify: error: {out}: is being written by magtune bag recover "
                                   f"(pid {os.getpid()}); wait until it ends, or choose another --out")
    assert cli_main(["bag", "recover", str(tiny), "-o", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["metadata.yaml", "rec_0.mcap"]  # no lock file left
    assert cli_main(["bag", "recover", str(tiny), "-o", str(tmp_path / "rec2")]) == 0


def test_a_lock_file_left_by_a_killed_run_does_not_count_as_output(tmp_path, capsys):
    """A killed writer leaves ``.magtune.lock`` (its flock died with it): the next run takes it, and
    the checks for an existing output (non-empty directory, --force) do not count it."""
    tiny = _tiny_bag(tmp_path / "in")
    rec = tmp_path / "rec"
    rec.mkdir()
    (rec / LOCK_NAME).write_text("999999999 magtune bag recover\n")
    assert cli_main(["bag", "recover", str(tiny), "-o", str(rec)]) == 0
    assert LOCK_NAME not in os.listdir(rec)
    for force, leftovers in (([], []), (["--force"], ["verify.md"])):
        out = tmp_path / f"v{len(force)}"
        out.mkdir()
        (out / LOCK_NAME).write_text("999999999 magtune verify\n")
        for name in leftovers:
            (out / name).write_text("earlier verdict\n")
        capsys.readouterr()
        # --also-ts outside the spec fails after the output checks: their message is not the one seen
        assert cli_main(["verify", GAINS, "--runs", "1", "--also-ts", "1000", "--out", str(out), *force]) == 2
        assert "--also-ts: 1000 s lies outside" in _one_line(capsys.readouterr().err)


# ---------------------------------------------------------------- bag files must be regular files

def _irregular_bags(tmp_path: Path) -> dict:
    """case -> (path given to the command, the file the error must name, what it is)."""
    fifo = tmp_path / "fifo.mcap"
    os.mkfifo(fifo)
    zero = tmp_path / "zero.mcap"
    zero.symlink_to("/dev/zero")
    listed = _tiny_bag(tmp_path, "listed")
    (listed / "listed_0.mcap").unlink()
    os.mkfifo(listed / "listed_0.mcap")
    meta = _tiny_bag(tmp_path, "meta")
    (meta / "metadata.yaml").unlink()
    os.mkfifo(meta / "metadata.yaml")
    return {"fifo": (fifo, fifo, "is a FIFO (named pipe)"),
            "dev_zero_link": (zero, zero, "is a symbolic link to a character device (/dev/zero)"),
            "listed_fifo": (listed, listed / "listed_0.mcap", "is a FIFO (named pipe)"),
            "metadata_fifo": (meta, meta / "metadata.yaml", "is a FIFO (named pipe)")}


COMMANDS = {"report": ["report", "{bag}", "--out", "{out}"], "replay": ["replay", "{bag}"],
            "bag info": ["bag", "info", "{bag}"], "bag recover": ["bag", "recover", "{bag}", "-o", "{out}"]}


@pytest.mark.parametrize("case", ["fifo", "dev_zero_link", "listed_fifo", "metadata_fifo"])
@pytest.mark.parametrize("command", list(COMMANDS))
def test_bag_that_is_not_a_regular_file_is_one_line(tmp_path, capsys, watchdog, command, case):
    given, named, what = _irregular_bags(tmp_path)[case]
    out = tmp_path / "out"
    argv = [a.format(bag=given, out=out) for a in COMMANDS[command]]
    capsys.readouterr()
    assert cli_main(argv) == 2
    line = _one_line(capsys.readouterr().err)
    assert line == f"magtune {command}: error: {named}: {what}, not a regular file; point it at a regular file"
    assert not out.exists()  # no output directory made for a bag that cannot be read


@pytest.mark.parametrize("command, case", [("report", "fifo"), ("replay", "listed_fifo"),
                                           ("bag recover", "dev_zero_link")])
def test_bag_that_is_not_a_regular_file_in_a_real_process(tmp_path, command, case):
    """The same through ``python -m magtune_core`` with a timeout: a hang fails the test."""
    given, named, what = _irregular_bags(tmp_path)[case]
    argv = [a.format(bag=given, out=tmp_path / "out") for a in COMMANDS[command]]
    r = subprocess.run([sys.executable, "-m", "magtune_core", *argv], capture_output=True, text=True, timeout=120)
    assert r.returncode == 2
    line = _one_line(r.stderr)
    assert line.startswith(f"magtune {command}: error: {named}: {what}, not a regular file")
    assert "free some space" not in line


# ---------------------------------------------------------------- bounded input files

def _big_inputs(tmp_path: Path) -> dict:
    """case -> (argv, the file named): 3 MB YAML (or JSON) in each kind of user file."""
    big = tmp_path / "big.yaml"
    big.write_text("controller:\n  ros__parameters:\n" + "".join(f"    k{i}: {i}.0\n" for i in range(200_000)))
    assert big.stat().st_size > 3_000_000
    meta = _tiny_bag(tmp_path, "meta")
    (meta / "metadata.yaml").write_bytes(big.read_bytes())
    camp = tmp_path / "camp"
    camp.mkdir()
    (camp / "runs.parquet").write_bytes(b"")
    (camp / "campaign.json").write_text('{"x": "' + "y" * 3_000_000 + '"}')
    return {"gains": (["analyze", str(big)], big),
            "spacecraft": (["--config", str(big), "analyze", GAINS], big),
            "campaign spec": (["campaign", str(big), "--runs", "1", "--out", str(tmp_path / "mc")], big),
            "design spec": (["verify", GAINS, "--spec", str(big), "--out", str(tmp_path / "v")], big),
            "scenario": (["sil", "--gains", GAINS, "--scenario", str(big)], big),
            "sil gains": (["sil", "--gains", str(big)], big),
            "bag metadata": (["bag", "info", str(meta)], meta / "metadata.yaml"),
            "campaign json": (["campaign-report", str(camp)], camp / "campaign.json")}


@pytest.mark.parametrize("case", ["gains", "spacecraft", "campaign spec", "design spec", "scenario", "sil gains",
                                  "bag metadata", "campaign json"])
def test_3_mb_input_file_is_refused_within_a_second(tmp_path, capsys, case):
    argv, named = _big_inputs(tmp_path)[case]
    cli_main(["analyze", str(tmp_path / "missing.yaml")])  # imports done: the time measured is the check's
    capsys.readouterr()
    t0 = time.perf_counter()
    assert cli_main(argv) == 2
    elapsed = time.perf_counter() - t0
    line = _one_line(capsys.readouterr().err)
    assert f"error: {named}: too large (" in line and "input files are limited to 1 MiB" in line
    assert elapsed < 1.0, f"{elapsed:.2f} s"
    assert not (tmp_path / "v").exists() and not (tmp_path / "mc").exists()  # no output directory left behind


@pytest.mark.parametrize("option, value", [("start", 1e300), ("playback_duration", 1e300), ("playback_until", 1e300),
                                           ("playback_until", -1e300), ("rate", 1e300), ("wait_subscribers", 1e300),
                                           ("start", float("nan")), ("rate", -1.0)])
def test_replay_numbers_are_range_checked(option, value):
    with pytest.raises(ConfigError, match=rf"^--{option.replace('_', '-')}: .*out of range"):
        check_numbers(ReplayOptions(**{option: value}))
    check_numbers(ReplayOptions(start=9e9, playback_duration=1.0, playback_until=-5.0, rate=0.0, wait_subscribers=3600))


def test_replay_start_1e300_is_one_line_not_a_traceback(tmp_path):
    tiny = _tiny_bag(tmp_path)
    r = subprocess.run([sys.executable, "-m", "magtune_core", "replay", str(tiny), "--start", "1e300"],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2
    assert _one_line(r.stderr) == ("magtune replay: error: --start: 1e+300: out of range 0 .. 9.2e+09 (seconds from "
                                   "the beginning of the bag; bag times are int64 nanoseconds)")


def test_sil_domain_id_is_0_to_232(capsys):
    assert cli_main(["sil", "--gains", GAINS, "--domain-id", "235"]) == 2
    assert _one_line(capsys.readouterr().err) == ("magtune sil: error: --domain-id: 235: expected a ROS_DOMAIN_ID in "
                                                  "0-232 (larger ids give DDS ports above 65535)")
    for ok in (0, 232, None):
        check_domain_id(ok)
    for bad in (-1, 233):
        with pytest.raises(ConfigError, match="--domain-id"):
            check_domain_id(bad)
    with pytest.raises(SystemExit):
        cli_main(["sil", "--help"])
    assert "ROS_DOMAIN_ID, 0-232" in " ".join(capsys.readouterr().out.split())


# ---------------------------------------------------------------- defaults independent of the working directory

def test_verify_default_campaign_from_another_working_directory(tmp_path):
    """From a directory without config/, the default campaign spec is still the repository's: the run
    gets past loading it (and stops at a later check, --also-ts, to stay short)."""
    r = subprocess.run([sys.executable, "-m", "magtune_core", "verify", GAINS, "--runs", "1", "--also-ts", "1000",
                        "--out", str(tmp_path / "v")], capture_output=True, text=True, timeout=120, cwd=tmp_path)
    assert r.returncode == 2
    assert _one_line(r.stderr).startswith("magtune verify: error: --also-ts: 1000 s lies outside the design spec's range")
    assert not (tmp_path / "v").exists()
