"""The tuner and the front on an existing Dask cluster (``--scheduler``, studies.cluster.executor):
a real `dask scheduler` and two `dask worker` processes on 127.0.0.1 (TLS, certificate files),
the candidates' evaluations run as tasks on both workers, and the tuned gain is bit-identical to
a local ``--workers 2`` run with the same seed (the evaluation is deterministic per gain and the
population is split the same way: one part per worker thread). Bad cluster options: one line
naming the option, exit 2, before any work."""
from __future__ import annotations

import numpy as np
import pytest
from dask_cluster import dask_cluster, tls_files, tls_options  # tests/support

from magtune_core.base.ament import ROOT
from magtune_core.cli import main
from magtune_core.design.cmaes import CmaSettings
from magtune_core.design.gains import load_gains
from magtune_core.design.model import AttitudeLTP
from magtune_core.design.params import SpacecraftParams
from magtune_core.design.pipeline import tune_gains
from magtune_core.design.sampled import HoldConstraint
from magtune_core.studies import cluster
from magtune_core.studies.front import run_front

MODEL = AttitudeLTP.from_params(SpacecraftParams())
#: A short tune: sigma = 60 from the LQ start under the default hold constraint (1 s, margin 2),
#: 200 evaluations (feasible-range coordinates from ~2,000 gains, then 25 generations of 8).
SIGMA, SEED, EVALS = 60.0, 3, 200


@pytest.fixture(scope="module")
def secured(tmp_path_factory):
    """(address, TlsFiles, the files) of a real TLS cluster of two single-thread workers."""
    tmp = tmp_path_factory.mktemp("cluster")
    tls = tls_files(tmp)
    with dask_cluster(tmp, tls) as (addr, _, _):
        yield addr, cluster.TlsFiles(str(tls["ca"]), str(tls["cert"]), str(tls["key"])), tls


@pytest.fixture(scope="module")
def local():
    """The reference: the same tune on a local pool of 2 processes."""
    return tune_gains(MODEL, SIGMA, seed=SEED, workers=2, cma=CmaSettings(max_evals=EVALS))


def test_tune_on_the_cluster_equals_local(secured, local):
    from distributed import get_task_stream

    addr, tls, _ = secured
    with cluster.executor(addr, tls) as ex:
        assert ex.workers == 2  # one part per worker thread
        with get_task_stream(ex.client) as stream:
            out = tune_gains(MODEL, SIGMA, seed=SEED, workers=7, cma=CmaSettings(max_evals=EVALS), executor=ex)
    np.testing.assert_array_equal(out.gains.K, local.gains.K)  # bit-identical
    assert out.result.evaluations == local.result.evaluations and out.gains.provenance["J"] == local.gains.provenance["J"]
    tasks = [t for t in stream.data if t["key"].startswith("_one_thread")]
    # every generation of 8 is split in two parts (the feasible-range scan too), on both workers
    assert len(tasks) >= EVALS // 8 and len({t["worker"] for t in tasks}) == 2


def test_tune_command_on_the_cluster(secured, local, tmp_path, capsys):
    addr, _, files = secured
    out = tmp_path / "g.yaml"
    assert main(["tune", "--sigma", f"{SIGMA:g}", "--seed", str(SEED), "--max-evals", str(EVALS), "--ts", "1",
                 "--gain-margin", "2", "--verify-runs", "0", "--quiet", "--out", str(out), "--scheduler", addr,
                 *tls_options(files)]) == 0
    np.testing.assert_array_equal(load_gains(out).K, local.gains.K)
    assert "warning" not in capsys.readouterr().err  # tls://: no warning


def test_front_on_the_cluster_equals_local(secured):
    addr, tls, _ = secured
    settings = CmaSettings(max_evals=48, workers=2)
    hold = HoldConstraint(1.0, 2.0)
    ref = run_front(MODEL, [SIGMA], settings, seed=SEED, hold=hold)
    with cluster.executor(addr, tls) as ex:
        pts = run_front(MODEL, [SIGMA], settings, seed=SEED, hold=hold, executor=ex)
    np.testing.assert_array_equal(pts[0].K, ref[0].K)
    assert pts[0].J == ref[0].J and pts[0].evaluations == ref[0].evaluations


@pytest.mark.parametrize("command", [["tune", "--sigma", "60"], ["front", "--sigmas", "60"]])
@pytest.mark.parametrize("extra, option, fix", [
    (["--scheduler", "127.0.0.1:8786"], "--scheduler", "expected tls://HOST:PORT or tcp://HOST:PORT"),
    (["--scheduler", "synchronous"], "--scheduler", "expected tls://HOST:PORT or tcp://HOST:PORT"),
    (["--tls-ca-file", "ca.pem"], "--tls-ca-file", "add --scheduler tls://HOST:PORT"),
    (["--scheduler", "tls://127.0.0.1:1", "--tls-ca-file", "nowhere.pem", "--tls-cert", "c", "--tls-key", "k"],
     "nowhere.pem", "--tls-ca-file: file not found"),
])
def test_bad_cluster_options_one_line_exit_2(command, extra, option, fix, tmp_path, capsys):
    out = ["--out", str(tmp_path / "g.yaml")] if command[0] == "tune" else ["--out-dir", str(tmp_path)]
    assert main([*command, *extra, *out]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and option in err[0] and fix in err[0], err
    assert not any(tmp_path.iterdir())  # nothing written, nothing started


def test_scheduler_is_a_cma_option(tmp_path, capsys):
    assert main(["tune", "--sigma", "60", "--method", "paper", "--scheduler", "tcp://127.0.0.1:1",
                 "--out", str(tmp_path / "g.yaml")]) == 2
    assert "--scheduler: is an option of --method cma" in capsys.readouterr().err


def test_tcp_to_the_secured_cluster_is_refused_one_line_exit_1(secured, tmp_path, capsys):
    """tcp:// is accepted with the campaign's warning; the TLS cluster refuses a plain-tcp client:
    one line naming the scheduler, exit 1, no file."""
    addr = secured[0].replace("tls://", "tcp://")
    assert main(["tune", "--sigma", "60", "--ts", "1", "--gain-margin", "2", "--scheduler", addr, "--quiet",
                 "--out", str(tmp_path / "g.yaml")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err[0] == (f"tune: warning: {addr} is unauthenticated; anyone who can reach it can run code on its workers "
                      "(use tls://, docs/campaigns.md)")
    assert len(err) == 2 and err[1].startswith(f"magtune tune: cannot reach the Dask scheduler {addr}")
    assert not (tmp_path / "g.yaml").exists()


@pytest.mark.parametrize("extra, option, fix", [
    (["--tls-ca-file", "ca.pem"], "--tls-ca-file", "add --scheduler tls://HOST:PORT"),
    (["--scheduler", "tls://127.0.0.1:1", "--tls-cert", "c"], "--tls-ca-file", "needs --tls-ca-file, --tls-cert and"),
    (["--scheduler", "tcp://127.0.0.1:1", "--tls-ca-file", "a", "--tls-cert", "b", "--tls-key", "c"], "--scheduler",
     "is not a tls:// address"),
])
def test_verify_takes_the_campaign_tls_options(extra, option, fix, tmp_path, capsys):
    assert main(["verify", str(ROOT / "config/gains/sigma_120.yaml"), "--runs", "1", "--out", str(tmp_path / "v"), *extra]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and option in err[0] and fix in err[0], err


def test_verify_on_the_secured_cluster(secured, tmp_path, capsys):
    """``verify --scheduler tls://... --tls-*`` (campaign's options): every period's campaign runs on
    the TLS cluster; a shipped gain passes (as in-process, tests/studies/test_verify.py)."""
    import json

    addr, _, files = secured
    out = tmp_path / "v"
    rc = main(["verify", str(ROOT / "config/gains/sigma_120.yaml"), "--runs", "2", "--out", str(out),
               "--scheduler", addr, *tls_options(files), "--no-progress"])
    assert rc == 0, capsys.readouterr().err[-800:]
    rec = json.loads((out / "verify.json").read_text())
    assert rec["passed"] and rec["periods"] == [1.0, 30.0] and rec["runs"] == 2
    for ts in ("1", "30"):
        meta = json.loads((out / f"ts_{ts}" / "campaign.json").read_text())
        assert meta["scheduler"] == addr and meta["secured"] is True and meta["workers"] == 2
