"""ROS 2 nodes over real DDS (separate processes): lockstep SIL equivalence, controller input
validation and diagnostics, parameter-file errors, clean shutdown.

Every test isolates itself with a ROS_DOMAIN_ID reserved through magtune_core.ros.process.DomainLock and
ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST, and stops every process it started in ``finally``.
"""
import math
import os
import signal
import subprocess
import sys
import time

import numpy as np
import pytest

from magtune_core.base.errors import ConfigError, SilError
from magtune_core.design.gains import Gains, load_gains, save_gains
from magtune_core.design.params import SpacecraftParams
from magtune_core.onboard.law import ProjectionController, linear_state
from magtune_core.ros import process, scenario, sil
from magtune_core.sim.simulate import simulate

pytestmark = pytest.mark.ros




# ------------------------------------------------------------------ SIL
def test_sil_one_orbit_matches_offline(gains60, tmp_path):
    procs = []
    run = sil.run_sil(gains60, orbits=1.0, log_dir=tmp_path, timeout=120,
                      on_start=lambda did, ps: procs.extend(ps))
    assert all(p.popen.poll() is not None for p in procs)  # nothing left running
    assert run.counters["missed_steps"] == 0 and run.counters["rejected_commands"] == 0
    n = int(round(SpacecraftParams().orbit_period))
    assert run.result.t.shape == (n + 1,)
    off = simulate(load_gains(gains60).K, SpacecraftParams(), steps=n, substeps=2)
    # key test: same trajectory at every controller step. Both sides run the same float64
    # operations (messages carry float64 exactly), so 1e-9 abs is a loose bound on zero.
    err = max(np.max(np.abs(run.result.q - off.q)), np.max(np.abs(run.result.w - off.w)),
              np.max(np.abs(run.result.x - off.x)), np.max(np.abs(run.result.m - off.m)))
    assert err <= 1e-9
    f = run.figures
    # converges: dw(0) transient peaks at ~2.6e-2 and is damped to < 1e-2 within the orbit
    assert f["peak_dq"] < 5e-2 and f["final_dq"] < 1e-2
    assert abs(f["final_dq"] - off.figures_of_merit()["final_dq"]) <= 1e-12
    assert "real-time factor" in run.summary()


def test_sil_failing_node_stops_everything(tmp_path, gains60):
    """A bad gains file is rejected by the runner before any process starts (ConfigError, exit 2
    in the CLI); a node that fails at start-up (here: a controller parameter override the
    runner does not pre-check) stops the whole run, and no process is left behind."""
    bad = tmp_path / "bad.yaml"
    save_gains(bad, Gains(np.zeros((3, 6)), 60.0))
    bad.write_text(bad.read_text().replace("sigma: 60.0", "sigma: sixty"))
    with pytest.raises(ConfigError, match="field 'sigma'"):
        sil.run_sil(bad, steps=10, log_dir=tmp_path, timeout=60)
    procs = []
    with pytest.raises(SilError, match="controller.*sigma"):
        sil.run_sil(gains60, steps=10, ts=1.0, log_dir=tmp_path, timeout=60, controller_params={"sigma": -60.0},
                    on_start=lambda did, ps: procs.extend(ps))
    assert procs and all(p.popen.poll() is not None for p in procs)


# ------------------------------------------------------------------ parameter files
def _run_controller(args, tmp_path, domain):
    exe = process.resolve_executable("controller")
    env = process.child_env(domain, process.package_prefix())
    return subprocess.run([str(exe), "--ros-args", *args], env=env, capture_output=True, text=True, timeout=30)


@pytest.mark.parametrize("edit, name", [
    (lambda t: t.replace("- -0.", "- -1.", 1).replace("    sigma:", "    - 1.0\n    sigma:"), "gain"),
    (lambda t: t.replace("sigma: 60.0", "sigma: -60.0"), "sigma"),
    (lambda t: t.replace("ts: 1.0", "ts: [1.0]"), "ts"),
])
def test_bad_gains_file_exits_with_one_line(tmp_path, gains60, edit, name):
    bad = tmp_path / "bad.yaml"
    bad.write_text(edit(gains60.read_text()))
    with process.DomainLock() as lock:
        r = _run_controller(["--params-file", str(bad)], tmp_path, lock.domain_id)
    assert r.returncode == 2
    lines = [ln for ln in r.stderr.strip().splitlines() if ln]
    assert len(lines) == 1 and f"parameter '{name}'" in lines[0] and lines[0].startswith("controller:")


def test_malformed_params_file(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("controller: {ros__parameters: {gain: [1.0, 2.0\n")
    with process.DomainLock() as lock:
        r = _run_controller(["--params-file", str(bad)], tmp_path, lock.domain_id)
    assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1 and "malformed YAML" in r.stderr


# ------------------------------------------------------------------ live controller, bad inputs
@pytest.fixture
def live_controller(gains60, tmp_path):
    """A controller process and an rclpy test node on a private domain."""
    import rclpy
    from rclpy.node import Node

    lock = process.DomainLock()
    os.environ["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    exe = process.resolve_executable("controller")
    env = process.child_env(lock.domain_id, process.package_prefix())
    log = open(tmp_path / "controller.log", "w")
    proc = subprocess.Popen([str(exe), "--ros-args", "--params-file", str(scenario.DEFAULT_SPACECRAFT), "--params-file",
                             str(gains60), "-p", "use_sim_time:=true"], env=env, stdout=log,
                            stderr=subprocess.STDOUT, start_new_session=True, preexec_fn=process.die_with_parent())
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=lock.domain_id)
    node = Node("test_probe", context=ctx)
    try:
        yield node, ctx, proc
    finally:
        node.destroy_node()
        rclpy.shutdown(context=ctx)
        process.stop_nodes([process.NodeProcess("controller", proc, tmp_path / "controller.log")])
        log.close()
        lock.release()


def test_controller_rejects_bad_inputs(live_controller, gains60):
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import Vector3Stamped
    from rclpy.executors import SingleThreadedExecutor
    from rosgraph_msgs.msg import Clock
    from sensor_msgs.msg import Imu, MagneticField

    sys.path.insert(0, str(process.package_prefix() / "lib" / f"python{sys.version_info[0]}.{sys.version_info[1]}"
                           / "site-packages"))
    from magtune_core.base.topics import TOPIC_ATTITUDE, TOPIC_DIPOLE, TOPIC_MAG
    from magtune_ros.inputs import ns_to_stamp, sec_to_ns, stamp_to_ns
    from magtune_ros.qos import CLOCK_QOS, LOCKSTEP_QOS

    node, ctx, proc = live_controller
    ex = SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    cmds, diags = [], {}
    node.create_subscription(Vector3Stamped, TOPIC_DIPOLE, cmds.append, LOCKSTEP_QOS)
    node.create_subscription(DiagnosticArray, "/diagnostics", lambda m: diags.update(
        {kv.key: kv.value for st in m.status if st.name == "magtune/controller" for kv in st.values}), 10)
    pub_clock = node.create_publisher(Clock, "/clock", CLOCK_QOS)
    pub_mag = node.create_publisher(MagneticField, TOPIC_MAG, LOCKSTEP_QOS)
    pub_att = node.create_publisher(Imu, TOPIC_ATTITUDE, LOCKSTEP_QOS)

    def spin(cond, timeout):
        end = time.monotonic() + timeout
        while time.monotonic() < end and not cond():
            assert proc.poll() is None, "controller died"
            ex.spin_once(timeout_sec=0.02)
        return cond()

    assert spin(lambda: pub_mag.get_subscription_count() and pub_att.get_subscription_count()
                and pub_clock.get_subscription_count(), 20), "controller not discovered"

    def set_clock(t):
        msg = Clock()
        msg.clock = ns_to_stamp(sec_to_ns(t))
        for _ in range(3):  # best-effort TimeSource subscription: repeat, then let it land
            pub_clock.publish(msg)
            spin(lambda: False, 0.05)

    def send(t, b=(2e-5, 1e-5, 5e-6), q=(1.0, 0.0, 0.0, 0.0), w=(1e-3, 2e-3, -1e-3)):
        stamp = ns_to_stamp(sec_to_ns(t))
        m = MagneticField()
        m.header.stamp = stamp
        m.magnetic_field.x, m.magnetic_field.y, m.magnetic_field.z = b
        a = Imu()
        a.header.stamp = stamp
        a.orientation.w, a.orientation.x, a.orientation.y, a.orientation.z = q
        a.angular_velocity.x, a.angular_velocity.y, a.angular_velocity.z = w
        pub_mag.publish(m)
        pub_att.publish(a)

    def expect_command(t, timeout=5.0):
        ok = spin(lambda: any(stamp_to_ns(m.header.stamp) == sec_to_ns(t) for m in cmds), timeout)
        assert ok, f"no command for t={t}"
        m = [m for m in cmds if stamp_to_ns(m.header.stamp) == sec_to_ns(t)][-1]
        return np.array([m.vector.x, m.vector.y, m.vector.z])

    # before any /clock the node's sim clock is 0: the stamps' order only (in the SIL the data
    # readers can match before the best-effort /clock reader; 3 s ahead was rejected before)
    send(9.0)
    expect_command(9.0, timeout=10.0)
    set_clock(10.0)
    send(10.0)
    m = expect_command(10.0, timeout=10.0)
    K = load_gains(gains60).K
    w0 = SpacecraftParams().orbit_rate
    ref = ProjectionController(K)(linear_state((1, 0, 0, 0), (1e-3, 2e-3, -1e-3), w0), np.array([2e-5, 1e-5, 5e-6]))
    assert np.array_equal(m, ref.m)  # same core law, float64 end to end: bit-identical

    set_clock(11.0)
    send(11.0, b=(math.nan, 1e-5, 5e-6))           # NaN field: rejected, no command
    set_clock(12.0)
    send(12.0, b=(0.0, 0.0, 0.0))                  # zero field: zero dipole + weak_field
    assert np.array_equal(expect_command(12.0), np.zeros(3))
    send(12.5, q=(2.0, 0.0, 0.0, 0.0))             # non-unit quaternion: rejected
    set_clock(20.0)
    send(13.0)                                     # 7 s old > 2 Ts: stale (both inputs)
    send(19.0)                                     # valid
    expect_command(19.0)
    send(18.5)                                     # older than the last accepted stamp
    send(30.0)                                     # 10 s in the future > 2 Ts
    send(19.5, w=(math.inf, 0.0, 0.0))             # Inf rate: rejected
    send(19.7, b=(1e308, 0.0, 0.0))                # finite but not physical (issue #10): rejected, counted
    want = {"rejected_nonfinite": 2, "weak_field": 1, "rejected_quaternion": 1, "stale_inputs": 2,
            "rejected_stamp": 4, "commands": 4, "rejected_implausible": 1}
    ok = spin(lambda: all(int(diags.get(k, -1)) == v for k, v in want.items()), 10.0)
    assert ok, f"diagnostics {diags} != expected {want}"
    stamps = sorted(stamp_to_ns(m.header.stamp) for m in cmds)
    assert stamps == [sec_to_ns(t) for t in (9.0, 10.0, 12.0, 19.0)]  # nothing for rejected inputs
    # stale data: the clock runs on without inputs -> held dipole zeroed once, node alive
    set_clock(25.0)
    assert spin(lambda: int(diags.get("stale_data", 0)) == 1, 5.0), diags
    assert proc.poll() is None


# ------------------------------------------------------------------ pacing and Ctrl-C
def test_real_time_factor_paces(gains60, tmp_path):
    run = sil.run_sil(gains60, steps=40, ts=1.0, real_time_factor=100.0, log_dir=tmp_path, timeout=60)
    # 40 s of sim time at 100x must take >= 0.4 s of wall time (sleep-based pacing: never early)
    assert run.wall_time >= 0.39 and run.counters["missed_steps"] == 0


def _magtune_node_pids(domain_id):
    """PIDs of magtune_ros executables running on ROS_DOMAIN_ID = domain_id (from /proc)."""
    pids = []
    for d in os.listdir("/proc"):
        if not d.isdigit():
            continue
        try:
            cmd = open(f"/proc/{d}/cmdline", "rb").read()
            env = open(f"/proc/{d}/environ", "rb").read().split(b"\0")
        except OSError:
            continue
        if b"lib/magtune_ros/" in cmd and f"ROS_DOMAIN_ID={domain_id}".encode() in env:
            pids.append(int(d))
    return pids


def test_ctrl_c_leaves_no_orphans(gains60, tmp_path):
    with process.DomainLock() as lock:
        did = lock.domain_id
    proc = subprocess.Popen([sys.executable, "-m", "magtune_core", "sil", "--gains", str(gains60), "--orbits", "5",
                             "--domain-id", str(did), "--log-dir", str(tmp_path)],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, start_new_session=True,
                            preexec_fn=process.die_with_parent())
    try:
        end = time.monotonic() + 30
        while time.monotonic() < end and len(_magtune_node_pids(did)) < 3:
            time.sleep(0.2)
        assert len(_magtune_node_pids(did)) == 3, "nodes did not start"
        time.sleep(1.0)
        proc.send_signal(signal.SIGINT)  # what Ctrl-C in a terminal sends
        out, err = proc.communicate(timeout=30)
        assert proc.returncode == 130 and "interrupted" in err
        assert _magtune_node_pids(did) == []
    finally:
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


def test_simulator_alone_counts_missed_steps(tmp_path):
    """No controller: every step times out, the (zero) command is held, the run still ends."""
    out = tmp_path / "alone.npz"
    with process.DomainLock() as lock:
        env = process.child_env(lock.domain_id, process.package_prefix())
        r = subprocess.run([str(process.resolve_executable("simulator")), "--ros-args", "--params-file",
                            str(scenario.DEFAULT_SPACECRAFT), "-p", "steps:=5",
                            "-p", "wait_for_peers:=false", "-p", "startup_timeout:=0.2", "-p",
                            "lockstep_timeout:=0.05", "-p", f"results_path:={out}"],
                           env=env, capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stderr
    import json

    from magtune_core.sim.simulate import SimResult
    res = SimResult.from_npz(out)
    counters = json.loads(str(res.info["counters"]))
    assert counters["missed_steps"] == 6 and counters["steps"] == 6  # t_0..t_5, none answered
    assert not np.any(res.m)
    off = simulate(np.zeros((3, 6)), SpacecraftParams(), steps=5)  # open loop = zero gain
    assert np.array_equal(res.q, off.q) and np.array_equal(res.w, off.w)


def test_seeded_sensor_noise_is_deterministic(gains60, tmp_path):
    noise = dict(mag_noise_std=2e-7, mag_quantum=5e-9, attitude_noise_std=1e-4, gyro_noise_std=1e-6,
                 gyro_bias=[1e-6, 0.0, -1e-6], seed=7)
    a = sil.run_sil(gains60, steps=200, ts=1.0, log_dir=tmp_path / "a", sensor_params=noise, timeout=60)
    b = sil.run_sil(gains60, steps=200, ts=1.0, log_dir=tmp_path / "b", sensor_params=noise, timeout=60)
    # an unanswered step shifts the noise stream of everything after it: say so first
    assert a.counters["missed_steps"] == 0 == b.counters["missed_steps"], (a.counters, b.counters)
    assert np.array_equal(a.result.q, b.result.q) and np.array_equal(a.result.m, b.result.m)
    off = simulate(load_gains(gains60).K, SpacecraftParams(), steps=200)
    d = np.max(np.abs(a.result.m - off.m))
    # noise changes the commands (|m| ~ 1 A m^2 here; 2e-7 T noise on 2.5e-5 T is ~1% -> > 1e-4)
    # but not the character of the loop (still well within 50% of the noise-free dipole scale)
    assert 1e-4 < d < 0.5 * np.max(np.abs(off.m))


def test_free_running_mode(gains60, tmp_path):
    """lockstep false: the simulator runs on a wall timer at real_time_factor and applies the
    latest command (typically one step old), so the loop is closed but not bit-identical."""
    run = sil.run_sil(gains60, steps=100, ts=1.0, lockstep=False, real_time_factor=50.0, log_dir=tmp_path,
                      timeout=60)
    assert run.wall_time >= 1.8  # 100 s at 50x = 2 s (timer jitter allowance 10%)
    # commands were applied on most steps. Not all: the controller takes inputs up to 2 Ts old and
    # zeroes its dipole after 2 Ts without one (stale_data), and on a free-running loop the
    # sensors -> controller lag is wall time (2 Ts = 40 ms here; at 200x = 10 ms a loaded CI
    # machine gave 71 of 100)
    assert np.count_nonzero(np.linalg.norm(run.result.m, axis=1)) > 80
    off = simulate(load_gains(gains60).K, SpacecraftParams(), steps=100)
    # a one-step command delay perturbs x by ~ Ts * |dx/dt| ~ 1e-3 at most over 100 s here
    assert np.max(np.abs(run.result.x - off.x)) < 5e-3


def test_ros_incompatible_provenance_is_named(tmp_path, gains60):
    """PyYAML accepts [1, 2.5] and nested lists; rcl does not: the node names the parameter."""
    bad = tmp_path / "bad.yaml"
    bad.write_text(gains60.read_text() + "    history:\n      costs: [1, 2.5]\n")
    with process.DomainLock() as lock:
        r = _run_controller(["--params-file", str(bad)], tmp_path, lock.domain_id)
    lines = r.stderr.strip().splitlines()
    assert r.returncode == 2 and len(lines) == 1 and "'history.costs'" in lines[0]
    with pytest.raises(ConfigError, match="history.costs"):  # the runner checks before starting anything
        sil.run_sil(bad, steps=5)


def test_simulator_disturbance_plugin(gains60, tmp_path):
    """A torque plug-in ('module:function' factory) enters the SIL plant exactly as offline."""
    from magtune_core.sim.dynamics import residual_dipole_disturbance

    run = sil.run_sil(gains60, steps=60, ts=1.0, log_dir=tmp_path, timeout=60, simulator_params=dict(
        residual_dipole=[0.0, 0.0, 0.0], disturbance_plugins=["tests.support.plugins:residual_dipole_x2"]))
    p = SpacecraftParams()
    off = simulate(load_gains(gains60).K, p, steps=60, residual_dipole=None,
                   disturbances=[residual_dipole_disturbance([2.0, 2.0, 2.0])])
    assert np.array_equal(run.result.q, off.q) and np.array_equal(run.result.m, off.m)
    with process.DomainLock() as lock:
        env = process.child_env(lock.domain_id, process.package_prefix())
        r = subprocess.run([str(process.resolve_executable("simulator")), "--ros-args", "--params-file", str(scenario.DEFAULT_SPACECRAFT), "-p",
                            "field_plugin:=no_such_module:f"], env=env, capture_output=True, text=True, timeout=30)
    assert r.returncode == 2 and "parameter 'field_plugin'" in r.stderr.strip().splitlines()[-1]


def test_spacecraft_schema_same_error_in_cli_and_node(tmp_path, gains60):
    """One schema per parameter file: the CLI and the controller node reject the same bad
    spacecraft file with the same words (field name and what was expected), exit status 2."""
    bad = tmp_path / "spacecraft.yaml"
    bad.write_text(scenario.DEFAULT_SPACECRAFT.read_text().replace("wheel_inertia: 0.01", "wheel_inertia: -0.01"))
    assert "wheel_inertia: -0.01" in bad.read_text()
    cli = subprocess.run([sys.executable, "-m", "magtune_core", "--config", str(bad), "analyze", str(gains60)],
                         capture_output=True, text=True, timeout=60)
    with process.DomainLock() as lock:
        node = _run_controller(["--params-file", str(bad), "--params-file", str(gains60)], tmp_path, lock.domain_id)
    expected = "expected a positive number, got -0.01"
    assert cli.returncode == 2 and node.returncode == 2
    assert "field 'wheel_inertia': " + expected in cli.stderr
    assert node.stderr.strip().splitlines() == [f"controller: parameter 'wheel_inertia': {expected}"]


def test_peer_that_never_comes_up_is_shown_with_the_startup_failure(tmp_path, gains60):
    """A controller left unconfigured (autostart false, no mode manager) never offers its dipole topic: the
    simulator gives up after startup_timeout (exit 3) naming what it waits for (the command's publisher), and the
    runner's error adds each peer's last log lines, so the user sees which node did not come up."""
    with pytest.raises(SilError, match=r"(?s)status 3:.*no subscriber/controller matched.*dipole_command: 0 of 1 "
                                       r"publisher \(the controller\).*--- controller:") as err:
        sil.run_sil(gains60, steps=10, ts=1.0, log_dir=tmp_path, timeout=60, startup_timeout=3.0,
                    controller_params={"autostart": False})
    assert "--- attitude_sensors:" in str(err.value), err.value
