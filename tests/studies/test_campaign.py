"""Monte Carlo campaigns (magtune_core.studies.campaign, magtune campaign / campaign-report):
spec validation, seeded draws, results independent of the executor (in-process, LocalCluster,
a real ``dask scheduler`` + two ``dask worker`` processes), failed and diverged runs kept."""
from __future__ import annotations

import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import yaml
from dask_cluster import dask_cluster, tls_files  # tests/support

from magtune_core.base.errors import ConfigError
from magtune_core.cli import main
from magtune_core.ros.process import die_with_parent  # the cluster dies with pytest
from magtune_core.studies import campaign, campaign_report

ROOT = Path(__file__).resolve().parents[2]
#: Short runs keep CI time small: 60 steps of 1 s in the full environment (two epochs, two RAANs).
SPEC = dict(
    campaign=dict(name="ci", seed=11, gains=["config/gains/sigma_120.yaml", "config/gains/sigma_60.yaml"],
                  environment="full", orbits=0.0107, ts=1.0, batch_size=3, history_step=10.0),
    dispersions=dict(inertia_rel_std=[0.05, 0.05, 0.05], residual_dipole_std=[0.3, 0.3, 0.3], attitude_max_deg=10.0,
                     rate_max=[5e-4, 5e-4, 5e-4], epoch_min="2026-01-01T00:00:00", epoch_max="2026-06-01T00:00:00",
                     raan_min_deg=0.0, raan_max_deg=360.0, mag_noise_std=1e-7, mag_bias_std=2e-7, gyro_noise_std=1e-5,
                     gyro_bias_std=2e-6, attitude_noise_std=1e-3, dipole_limit_min=20.0, dipole_limit_max=50.0),
    criteria=dict(settle_threshold_deg=12.0, max_settling_orbits=0.005, max_pointing_deg=15.0),
)
RUNS = 4
#: Figures compared between executors: each run is computed by the same code on the same inputs,
#: whatever process runs it, so they must agree exactly (NaN == NaN for never-settled runs).
COLUMNS = ("run", "gains", "status", "passed", "settling_time", "max_pointing_deg", "rms_pointing_deg",
           "final_pointing_deg", "peak_dipole", "rms_dipole", "saturation_fraction", "inertia_x", "raan_deg", "epoch")


def _write_spec(tmp_path, spec=None, name="spec.yaml") -> Path:
    p = tmp_path / name
    p.write_text(yaml.safe_dump(spec or SPEC))
    return p


def _columns_equal(a: dict, b: dict):
    for c in COLUMNS:
        x, y = a[c], b[c]
        if x.dtype.kind == "f":
            np.testing.assert_array_equal(x, y, err_msg=c)
        else:
            assert list(x) == list(y), c


@pytest.fixture(scope="module")
def reference(tmp_path_factory):
    """The campaign run in this process (no Dask): the reference of the executor tests."""
    tmp = tmp_path_factory.mktemp("ref")
    spec = campaign.load_spec(_write_spec(tmp))
    campaign.run_campaign(spec, RUNS, tmp / "out", scheduler="synchronous", progress=False)
    return tmp / "out"


def test_reference_campaign_outputs(reference):
    cols = campaign.read_runs(reference)
    assert len(cols["run"]) == 2 * RUNS  # every dispersion with each gains file
    assert set(cols["status"]) == {"ok"}
    h = campaign.read_histories(reference)
    assert h["pointing_deg"].shape == (2 * RUNS, 7) and h["t"].tolist() == [0, 10, 20, 30, 40, 50, 60]  # 60 steps
    # the same dispersion with both gains files (paired comparison), different outcomes
    assert list(cols["inertia_x"][:RUNS]) == list(cols["inertia_x"][RUNS:])
    # (the peak dipole is no test of that: in these 60-s runs from up to 10 deg both gains saturate the
    # dipole from the start, so their peaks are the same per-axis limit; the pointing differs)
    assert not np.any(cols["rms_pointing_deg"][:RUNS] == cols["rms_pointing_deg"][RUNS:])
    # figures: the stored history samples are samples of the full-resolution series
    assert np.all(cols["final_pointing_deg"] == pytest.approx(h["pointing_deg"][:, -1], rel=1e-6))


def test_draws_depend_on_seed_and_index_only(tmp_path):
    spec = campaign.load_spec(_write_spec(tmp_path))
    a = campaign.draw_run(spec, 7)
    for _ in range(2):
        campaign.draw_run(spec, 3)
    b = campaign.draw_run(spec, 7)
    assert np.array_equal(a["inertia"], b["inertia"]) and a["epoch"] == b["epoch"]
    d = [campaign.draw_run(spec, i) for i in range(300)]
    ang = np.array([r["attitude_angle_deg"] for r in d])
    rel = np.array([r["inertia"] for r in d]) / spec.p.inertia - 1
    raan = np.array([r["raan_deg"] for r in d])
    # U(0, 10 deg) angle, unit axis; inertia within the 3-sigma clip; RAAN over its range
    assert 0 <= ang.min() and ang.max() <= 10 and 4 < ang.mean() < 6
    assert np.all(np.abs(rel) <= 0.15 + 1e-12) and 0.04 < rel.std() < 0.06
    assert raan.min() < 20 and raan.max() > 340
    assert all(abs(np.linalg.norm(r["q0"]) - 1) < 1e-12 for r in d)


def test_local_cluster_equals_in_process(reference, tmp_path):
    """The default executor (a LocalCluster, here 2 worker processes) through the command line."""
    out = tmp_path / "lc"
    assert main(["campaign", str(_write_spec(tmp_path)), "--runs", str(RUNS), "--out", str(out), "--workers", "2",
                 "--no-progress"]) == 0
    _columns_equal(campaign.read_runs(out), campaign.read_runs(reference))
    meta = yaml.safe_load((out / "campaign.json").read_text())
    assert meta["workers"] == 2 and meta["scheduler"] == "LocalCluster" and meta["batches"] == 4


def test_external_dask_cluster_equals_in_process(reference, tmp_path):
    """A real `dask scheduler` and two `dask worker` processes on localhost (--scheduler tcp://...)."""
    with dask_cluster(tmp_path) as (addr, _, _):
        out = tmp_path / "ext"
        assert main(["campaign", str(_write_spec(tmp_path)), "--runs", str(RUNS), "--out", str(out), "--scheduler", addr,
                     "--no-progress"]) == 0
        _columns_equal(campaign.read_runs(out), campaign.read_runs(reference))
        meta = yaml.safe_load((out / "campaign.json").read_text())
        assert meta["workers"] == 2 and meta["scheduler"] == addr and meta["secured"] is False
        # both workers took part (4 tasks on 2 single-thread workers)
        assert all("w" in (tmp_path / f"worker{i}.log").read_text() for i in (1, 2))


def _kill_when_busy(addr, sec, victim: subprocess.Popen, name: str, stop: threading.Event, seen: list):
    """SIGKILL the worker process ``victim`` (Dask name ``name``) as soon as the scheduler shows a
    campaign task processing on it (issue 32 item 3: a worker lost mid-campaign)."""
    from distributed import Client

    with Client(addr, timeout="10s", security=sec) as c:
        while not stop.is_set():
            info = c.scheduler_info(n_workers=-1)["workers"]
            mine = [a for a, w in info.items() if w.get("name") == name]
            busy = c.processing(workers=mine) if mine else {}
            if any("run_batch" in str(k) for keys in busy.values() for k in keys):
                victim.send_signal(signal.SIGKILL)
                seen.append(list(busy.values()))
                return
            time.sleep(0.02)


def test_worker_killed_mid_campaign(reference, tmp_path, capsys):
    """A secured external cluster (tls://, --tls-* files; two `dask worker --no-nanny` processes,
    so a killed worker stays dead): w1 is SIGKILLed while it runs a batch. Every run is present
    with exactly the figures of the undisturbed in-process campaign (each batch is recomputed from
    the spec, seed and indices alone, so equality is exact), and the command exits 0. Before,
    every run came back failed (FutureCancelledError: the scattered spec was lost) with exit 0."""
    tls = tls_files(tmp_path)
    with dask_cluster(tmp_path, tls, nanny=False) as (addr, workers, sec):
        stop, seen = threading.Event(), []
        killer = threading.Thread(target=_kill_when_busy, args=(addr, sec, workers["w1"], "w1", stop, seen))
        killer.start()
        out = tmp_path / "killed"
        try:
            rc = main(["campaign", str(_write_spec(tmp_path)), "--runs", str(RUNS), "--out", str(out), "--scheduler", addr,
                       "--tls-ca-file", str(tls["ca"]), "--tls-cert", str(tls["cert"]), "--tls-key", str(tls["key"]),
                       "--no-progress"])
        finally:
            stop.set()
            killer.join(timeout=20)
        assert seen, "w1 never ran a campaign task (the kill did not happen mid-campaign)"
        assert workers["w1"].wait(timeout=10) == -signal.SIGKILL
        assert rc == 0, capsys.readouterr().err[-800:]
        cols = campaign.read_runs(out)
        assert set(cols["status"]) == {"ok"}
        _columns_equal(cols, campaign.read_runs(reference))
        meta = yaml.safe_load((out / "campaign.json").read_text())
        assert meta["secured"] is True and meta["failed_runs"] == [] and meta["total_runs"] == 2 * RUNS


def test_runs_that_never_complete_are_listed_and_exit_1(tmp_path, capsys, monkeypatch):
    """A batch whose task can never complete (here: the one holding run 3 raises on every attempt,
    outside run_batch's own per-run isolation): its runs are failed with the reason, listed by
    index on stderr, and the command exits 1 (it exited 0 before); the other runs are kept."""
    real = campaign.run_batch

    def flaky(spec, jobs, steps, every):
        if any(i == 3 for _, i in jobs):
            raise ConnectionError("worker lost (injected)")
        return real(spec, jobs, steps, every)

    monkeypatch.setattr(campaign, "run_batch", flaky)
    spec = yaml.safe_load(yaml.safe_dump(SPEC))
    spec["campaign"]["gains"] = spec["campaign"]["gains"][:1]
    out = tmp_path / "o"
    rc = main(["campaign", str(_write_spec(tmp_path, spec)), "--runs", str(RUNS), "--out", str(out), "--workers", "1",
               "--no-progress"])
    err = capsys.readouterr().err
    assert rc == 1, err[-800:]
    cols = campaign.read_runs(out)
    assert cols["status"].tolist() == ["ok", "ok", "ok", "failed"]  # batches of 3: runs 0-2, 3
    assert "1 of 4 runs did not complete" in err
    assert "run 3 (config/gains/sigma_120.yaml): ConnectionError: worker lost (injected)" in err
    meta = yaml.safe_load((out / "campaign.json").read_text())
    assert meta["resubmitted"] == campaign.RESUBMITS and meta["failed_runs"][0]["run"] == 3


def test_failed_and_diverged_runs_are_kept(tmp_path, monkeypatch):
    """Run 1 raises while set up (failed, with its message), run 2 spins at 2 rad/s (diverged);
    the other runs of the same batch are unaffected, every run has a row, the report lists them."""
    spec = campaign.load_spec(_write_spec(tmp_path))
    good = campaign.run_batch(spec, [(0, 0), (0, 3)], spec.steps(), spec.record_every())["rows"]
    real_draw = campaign.draw_run

    def draw(spec_, i):
        r = real_draw(spec_, i)
        if i == 1:
            raise RuntimeError("orbit propagation failed (injected)")
        if i == 2:
            r["dw0"] = np.array([2.0, 0.0, 0.0])
        return r

    monkeypatch.setattr(campaign, "draw_run", draw)
    out = tmp_path / "bad"
    spec.campaign["gains"] = spec.campaign["gains"][:1]
    spec.gains_files, spec.K = spec.gains_files[:1], spec.K[:1]
    campaign.run_campaign(spec, 4, out, scheduler="synchronous", progress=False)
    cols = campaign.read_runs(out)
    assert cols["status"].tolist() == ["ok", "failed", "diverged", "ok"]
    assert "injected" in cols["error"][1] and not cols["passed"][1] and not cols["passed"][2]
    # the batch was re-run one run at a time to isolate run 1: same runs, but each orbit now
    # propagated alone instead of in a batched ephemeris (both within the single-run tolerance,
    # ~1e-5 m apart): the figures agree to ~1e-11 relative
    for k, row in zip((0, 3), good):
        assert cols["peak_dipole"][k] == pytest.approx(row["peak_dipole"], rel=1e-9)
        assert cols["settling_time"][k] == row["settling_time"]
    md = campaign_report.write_report(out)
    assert "| 1 | config/gains/sigma_120.yaml | failed | RuntimeError: orbit propagation failed (injected) |" in md
    assert "| 2 | config/gains/sigma_120.yaml | diverged |" in md
    assert (out / "envelopes.png").stat().st_size > 10_000 and (out / "histograms.png").stat().st_size > 10_000


def test_report_command(reference, capsys):
    assert main(["campaign-report", str(reference)]) == 0
    text = (reference / "summary.md").read_text()
    assert "| ok | 8 |" in text and "## Worst runs" in text and "| settling_time | s |" in text
    assert (reference / "envelopes.png").is_file() and (reference / "histograms.png").is_file()


@pytest.mark.parametrize("section, key, value, expect", [
    ("campaign", "seed", "x", "field 'seed': expected an integer"),
    ("campaign", "orbitz", 5, "field 'campaign.orbitz': unknown field"),
    ("campaign", "environment", "moon", "field 'environment': expected one of paper, full"),
    ("dispersions", "inertia_rel_std", [0.1, 0.1], "field 'inertia_rel_std': expected a list of 3 numbers"),
    ("dispersions", "epoch_max", "yesterday", "field 'dispersions.epoch_max': expected an ISO 8601 UTC date/time"),
    ("dispersions", "raan_max_deg", -5.0, "field 'dispersions.raan_max_deg': must be >= raan_min_deg"),
    ("campaign", "gains", "nowhere.yaml", "field 'campaign.gains': file not found: nowhere.yaml"),
    ("criteria", "max_pointing_deg", -1.0, "field 'max_pointing_deg': expected a positive number"),
])
def test_bad_spec_one_line_exit_2(tmp_path, capsys, section, key, value, expect):
    spec = yaml.safe_load(yaml.safe_dump(SPEC))
    spec[section][key] = value
    p = _write_spec(tmp_path, spec)
    with pytest.raises(ConfigError, match=expect.replace("(", r"\(")):
        campaign.load_spec(p)
    assert main(["campaign", str(p), "--runs", "2", "--out", str(tmp_path / "o")]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and expect in err and "Traceback" not in err
    assert not (tmp_path / "o").exists()  # nothing started


def test_refuses_non_empty_out_without_force(tmp_path, capsys):
    p = _write_spec(tmp_path)
    out = tmp_path / "used"
    out.mkdir()
    (out / "notes.txt").write_text("mine")
    assert main(["campaign", str(p), "--runs", "1", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "--out is not empty; choose a new directory or add --force" in err and len(err.strip().splitlines()) == 1
    assert main(["campaign", str(p), "--runs", "1", "--out", str(out), "--force", "--scheduler", "synchronous",
                 "--no-progress"]) == 0
    assert (out / "notes.txt").read_text() == "mine" and (out / "runs.parquet").is_file()  # only our outputs replaced
    assert main(["campaign", str(p), "--runs", "0", "--out", str(tmp_path / "x")]) == 2
    assert main(["campaign", str(p), "--runs", "1", "--out", str(tmp_path / "x"), "--scheduler", "localhost:1"]) == 2


#: A second client, in its own process (as an intruder would be): connects to argv[1] with no
#: credentials, someone else's temporary certificate or plain tcp://, runs a task if it can, and
#: prints the outcome (os._exit: a refused Client's clean-up can hang at interpreter exit).
INTRUDER = r"""
import operator, os, sys
from distributed import Client
from distributed.security import Security
addr, mode = sys.argv[1], sys.argv[2]
kw = dict(security=Security.temporary()) if mode == "other-cert" else {}
if mode == "tcp":
    addr = addr.replace("tls://", "tcp://")
try:
    c = Client(addr, timeout="5s", **kw)
    print("CONNECTED", c.submit(operator.add, 1, 2).result(), flush=True)
except BaseException as e:
    print("REFUSED", type(e).__name__, str(e).splitlines()[0][:200], flush=True)
os._exit(0)
"""


def test_local_cluster_is_closed_to_other_clients():
    """The campaign's LocalCluster (studies.cluster.local_cluster, what run_campaign starts) speaks
    TLS and requires its own temporary certificate: its client runs a task; a second process's
    client without credentials, with another certificate or over plain tcp://, and a raw TLS
    handshake without a client certificate are all refused (before: tcp:// without
    authentication, a second process ran code on the workers). Its HTTP server serves no route
    and is not on 8787 (before: 8787 served the scheduler's pages)."""
    import operator
    import ssl
    import urllib.error
    import urllib.request

    from distributed import Client

    from magtune_core.studies import cluster

    with cluster.local_cluster(1) as (lc, sec):
        addr = lc.scheduler_address
        assert addr.startswith("tls://127.0.0.1:")
        with Client(lc, security=sec) as own:
            assert own.submit(operator.add, 1, 2).result() == 3
        expect = {"no-credentials": "TLS expects a `ssl_context`", "other-cert": "TLS certificate does not match",
                  "tcp": "Connection reset by peer"}
        for mode, why in expect.items():
            r = subprocess.run([sys.executable, "-c", INTRUDER, addr, mode], capture_output=True, text=True, timeout=60,
                               preexec_fn=die_with_parent())
            assert r.stdout.startswith("REFUSED") and why in r.stdout, (mode, r.stdout, r.stderr[-500:])
        host, port = addr[len("tls://"):].rsplit(":", 1)
        ctx = ssl.create_default_context()
        ctx.check_hostname, ctx.verify_mode = False, ssl.CERT_NONE
        got = None
        try:  # the server's alert (CERTIFICATE_REQUIRED) or its close (EOF) wins the race: either is a refusal
            with socket.create_connection((host, int(port)), timeout=5) as raw, ctx.wrap_socket(raw) as t:
                t.sendall(b"\0" * 8)
                got = t.recv(8)
        except (ssl.SSLError, ConnectionResetError) as exc:
            assert "CERTIFICATE_REQUIRED" in str(exc) or "EOF" in str(exc) or isinstance(exc, ConnectionResetError), exc
        assert not got  # nothing ever comes back to a peer without the certificate
        http = lc.scheduler.http_server.port
        assert http != 8787
        for route in ("/health", "/info/main/workers.html", "/metrics", "/json/identity.json"):
            with pytest.raises(urllib.error.HTTPError, match="404"):
                urllib.request.urlopen(f"http://127.0.0.1:{http}{route}", timeout=5)


@pytest.mark.parametrize("extra, expect", [
    (["--scheduler", "tls://127.0.0.1:1"], "a tls:// scheduler needs --tls-ca-file, --tls-cert and --tls-key"),
    (["--scheduler", "tls://127.0.0.1:1", "--tls-ca-file", "nowhere.pem", "--tls-cert", "c", "--tls-key", "k"],
     "nowhere.pem: --tls-ca-file: file not found"),
    (["--tls-cert", "cert.pem"], "TLS files are for an existing cluster"),
    (["--scheduler", "tcp://127.0.0.1:1", "--dashboard"], "only for the LocalCluster"),
])
def test_cluster_options_one_line_exit_2(tmp_path, capsys, extra, expect, monkeypatch):
    """Security options are checked before anything starts (no connection attempt, no output dir);
    the Dask configuration's TLS settings are cleared for the call."""
    import dask

    with dask.config.set({"distributed.comm.tls.ca-file": None, "distributed.comm.tls.client.cert": None}):
        rc = main(["campaign", str(_write_spec(tmp_path)), "--runs", "1", "--out", str(tmp_path / "o"), *extra])
    err = capsys.readouterr().err.strip()
    assert rc == 2 and expect in err and len(err.splitlines()) == 1, err
    assert not (tmp_path / "o").exists()


# --- deployment campaigns (campaign.modes) ---------------------------------------------------------------
#: A small deployment: 8 runs tumbling at up to 2 deg/s per axis from uniformly random attitudes, 3 orbits of
#: the full environment with sensor noise, the flight modes flown (DETUMBLE -> ACQUISITION -> POINTING).
DEPLOY = dict(
    campaign=dict(name="dep", seed=5, gains="config/gains/sigma_60.yaml", environment="full", orbits=3.0, ts=1.0,
                  batch_size=8, history_step=60.0, modes=True),
    modes=dict(detumble_exit_time=600.0, handover_time=600.0),
    dispersions=dict(inertia_rel_std=[0.05, 0.05, 0.05], residual_dipole_std=[0.3, 0.3, 0.3], attitude_uniform=True,
                     rate_mean=[0.0, 0.0, 0.0], rate_max=[0.0349, 0.0349, 0.0349], raan_min_deg=0.0, raan_max_deg=360.0,
                     mag_noise_std=1e-7, gyro_noise_std=1e-5, attitude_noise_std=1e-3, dipole_limit_min=40.0,
                     dipole_limit_max=50.0),
    criteria=dict(settle_threshold_deg=2.0, max_settling_orbits=2.5, max_deployment_orbits=2.5),
)


@pytest.fixture(scope="module")
def deployment(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("dep")
    spec = campaign.load_spec(_write_spec(tmp, DEPLOY))
    campaign.run_campaign(spec, 8, tmp / "out", scheduler="synchronous", progress=False)
    return spec, tmp / "out"


def test_deployment_campaign_detumbles_and_points(deployment):
    spec, out = deployment
    cols = campaign.read_runs(out)
    assert spec.substeps.levels == (2,)  # |w| <= sqrt(3) 2 deg/s + W0 = 0.062 rad/s: 2 RK4 steps keep |w| h <= 0.05 rad
    assert set(cols["status"]) == {"ok"} and len(cols["run"]) == 8
    det, pnt, sett = (cols[k].astype(float) for k in ("detumble_time", "pointing_time", "settled_time"))
    # detumbled: never before the 600-s persistence (exactly 600 s for a run drawn already calm: run 2, measured)
    # and, from <= 3.5 deg/s, well under an orbit (5674 s; measured 1457-2286 s)
    assert np.all(np.isfinite(det)) and np.all(det >= 600.0) and np.all(det < 5674.0) and np.sum(det > 600.0) >= 6
    # POINTING after the 600-s hand-over persistence, settled at or after it, before the end
    assert np.all(pnt >= det + 600.0) and np.all(sett >= pnt) and np.all(sett < 3 * 5674.0)
    assert np.all(cols["transitions"] >= 2) and set(cols["final_mode"]) == {"POINTING"}
    assert cols["reached_pointing"].all() and cols["passed"].all()
    meta = yaml.safe_load((out / "campaign.json").read_text())
    assert meta["modes"]["detumble_exit_time"] == 600.0 and meta["campaign"]["modes"] is True


def test_deployment_report_has_percentiles_and_failures(deployment, tmp_path):
    _, out = deployment
    md = campaign_report.write_report(out)
    assert "## Deployment" in md and "| settled_time | s |" in md and "| detumble_time | s |" in md
    assert "No deployment failure" in md
    # a run that never reached POINTING is listed with its reason (the verdict, on a copy of a row)
    row = dict(status="ok", settling_time=1.0, settled_time=float("nan"), reached_pointing=False, final_mode="DETUMBLE",
               **{k: float("nan") for k in ("max_pointing_deg", "rms_pointing_deg", "peak_dipole", "saturation_fraction",
                                            "steady_saturation_fraction")})
    ok, why = campaign.verdict(row, campaign.load_spec(_write_spec(tmp_path, DEPLOY)).criteria, 5674.0)
    assert not ok and why == "never reached POINTING"


def test_uniform_attitude_draw_and_the_other_draws_unchanged(tmp_path):
    spec = campaign.load_spec(_write_spec(tmp_path, DEPLOY))
    off = campaign.load_spec(_write_spec(tmp_path, dict(DEPLOY, dispersions=dict(DEPLOY["dispersions"], attitude_uniform=False)),
                                         name="off.yaml"))
    a, b = campaign.draw_run(spec, 3), campaign.draw_run(off, 3)
    for k in ("inertia", "residual_dipole", "dw0", "mag_bias", "gyro_bias"):  # the new draw comes last
        assert np.array_equal(a[k], b[k]), k
    ang = np.radians([campaign.draw_run(spec, i)["attitude_angle_deg"] for i in range(2000)])
    # uniform on SO(3): angle density (1 - cos t) / pi, mean pi/2 + 2/pi = 126.5 deg; the sample mean's std is
    # ~0.65 deg at N = 2000 (angle std ~29 deg), so +-3 deg is a 4.6-sigma bound; half the angles above 2.02 rad
    # would be the U(0, 180 deg) angle's fault (its mean is 90 deg)
    assert abs(np.degrees(ang.mean()) - np.degrees(np.pi / 2 + 2 / np.pi)) < 3.0
    assert ang.max() <= np.pi + 1e-12 and np.mean(ang < np.pi / 2) == pytest.approx((np.pi / 2 - 1) / np.pi, abs=0.03)


def test_modes_off_campaign_is_todays(reference, tmp_path):
    """`campaign.modes: false` (the default) runs the pointing campaign unchanged: the same table as the
    reference and no deployment column (bit for bit against the code before deployment campaigns was checked
    when they were added: a 10-run, 0.3-orbit full-environment campaign with noise, every column and history)."""
    out = tmp_path / "off"
    spec = campaign.load_spec(_write_spec(tmp_path, dict(SPEC, campaign=dict(SPEC["campaign"], modes=False))))
    campaign.run_campaign(spec, RUNS, out, scheduler="synchronous", progress=False)
    cols = campaign.read_runs(out)
    _columns_equal(cols, campaign.read_runs(reference))
    assert not {k for k, _ in campaign.MODE_FIGURES} & set(cols)


@pytest.mark.parametrize("change, field", [
    (dict(modes=dict(detumble_exit_time=600.0)), "modes"),  # a modes section without campaign.modes
    (dict(modes=dict(detumble_entry_rate=1e-3)), "detumble_entry_rate"),  # below the exit rate: no hysteresis
    (dict(modes=dict(bdot_cutoff=-1.0)), "bdot_cutoff"),
    (dict(torquers=dict(torquer_off_time=1.0)), "torquer_off_time"),  # = ts: the torquers would never drive
    (dict(torquers=dict(torquer_off_time=0.1234567)), "torquer_off_time"),  # on no grid of <= 1000 sub-steps
    (dict(torquers=dict(torquer_coupling=[1e-2] * 9)), "torquer_coupling"),  # above 1e-3 T/(A m^2)
    (dict(torquers=dict(coupling=[0.0] * 9)), "torquers.coupling"),  # not a field of the schema
])
def test_deployment_spec_errors_name_the_field(tmp_path, change, field):
    raw = dict(DEPLOY, **change)
    if field == "modes":
        raw["campaign"] = dict(DEPLOY["campaign"], modes=False)
    with pytest.raises(ConfigError, match=field):
        campaign.load_spec(_write_spec(tmp_path, raw))


def test_torquers_section_reaches_every_run(reference, tmp_path):
    """Section ``torquers`` (the nodes' TORQUER_FIELDS): the campaign's runs are simulate_batch's with that
    Torquers on the same draws (same code path, so equal exactly), the switch-off on the RK4 grid (5 sub-steps
    at ts 1 s, off 0.2 s), recorded in campaign.json, and not the reference's (the coupling and the
    duty cycle change every run)."""
    from magtune_core.onboard.torquers import Torquers, dipole_coupling
    from magtune_core.sim.batch import simulate_batch

    C = [float(x) for x in dipole_coupling([0.0, 0.0, 0.5]).ravel()]
    raw = dict(SPEC, torquers=dict(torquer_coupling=C, torquer_off_time=0.2))
    spec = campaign.load_spec(_write_spec(tmp_path, raw))
    assert spec.substeps.levels == (5,) and spec.batch_torquers() == Torquers(tuple(C), 0.2)
    campaign.run_campaign(spec, RUNS, tmp_path / "out", scheduler="synchronous", progress=False)
    cols, ref = campaign.read_runs(tmp_path / "out"), campaign.read_runs(reference)
    meta = yaml.safe_load((tmp_path / "out" / "campaign.json").read_text())
    assert meta["substeps"] == [5] and meta["torquers"]["torquer_off_time"] == 0.2
    jobs = [(0, i) for i in range(RUNS)]
    draws = [campaign.draw_run(spec, i) for _, i in jobs]
    res = simulate_batch(campaign._batch_runs(spec, draws, [0] * RUNS), ts=1.0, steps=spec.steps(), substeps=5,
                         full_series=True, torquers=Torquers(tuple(C), 0.2))
    first = cols["gains_index"] == 0
    # the campaign's batches are of 3 runs, this one of 4: numpy's vectorized sums group differently
    # (measured 3e-12 relative), so equal to 1e-9, far below the coupling's own effect asserted next
    np.testing.assert_allclose(cols["peak_dipole"][first], res.m_norm.max(axis=1), rtol=1e-9)
    assert np.all(np.abs(cols["peak_dipole"] / ref["peak_dipole"] - 1.0) > 1e-6)
