"""Replay of a SIL recording into a fresh controller reproduces the recorded dipole commands.

1. ``magtune sil`` (magtune_core.ros.sil.run_sil) runs simulator + sensors + controller with
   ``--bag``: our recorder writes the run.
2. A new controller process (same gains) gets only the recorded sensor topics from the
   player (with /clock); a second recorder records its dipole commands.
3. Decoded commands are compared by stamp. The controller is a pure function of each stamped
   input pair (ZOH period = input period), inputs cross CDR bit-exactly, so the values must be
   identical; we allow 1e-12 relative for libm/BLAS differences between processes.
"""
from __future__ import annotations

import time

import numpy as np
import pytest
from bagproc import Procs, executable, ros_env

from magtune_core import bags as bag
from magtune_core.bags.decode import Decoder, stamp_ns
from magtune_core.base.topics import ATTITUDE, DIPOLE, FRAME_BODY, FRAME_ORBITAL, MAG, MARKERS, TF, TRUTH
from magtune_core.design.gains import save_gains
from magtune_core.design.lq import lq_gains
from magtune_core.design.model import AttitudeLTP
from magtune_core.design.params import SpacecraftParams
from magtune_core.ros import scenario, sil

pytestmark = [pytest.mark.ros, pytest.mark.timeout(180)]
STEPS = 300


def _dipoles(path) -> dict[int, tuple]:
    d = Decoder()
    out = {}
    for m in bag.iter_messages(path, topics=[DIPOLE]):
        v = d.decode(m.data, m.type)
        out[stamp_ns(v)] = (v.vector.x, v.vector.y, v.vector.z)
    return out


def test_replayed_sensors_reproduce_dipole_commands(tmp_path):
    gains = tmp_path / "sigma_60.yaml"
    save_gains(gains, lq_gains(AttitudeLTP.from_params(SpacecraftParams()), 60.0, 1.0))
    rec1 = tmp_path / "sil_run"
    # paced at 100x real time: the recorder's DDS discovery of the simulator (it is not one of
    # the simulator's lockstep peers) then costs at most a few steps, recovered from the
    # transient-local history (depth 100) of the lockstep topics
    run = sil.run_sil(gains, steps=STEPS, bag=rec1, log_dir=tmp_path / "sil_logs", timeout=120,
                      real_time_factor=100.0)
    assert run.counters["missed_steps"] == 0
    # the bag alone gives the SIL's own figures of merit (computed by the simulator from its
    # in-memory trajectory): every truth sample recorded, float64 carried exactly by CDR
    from magtune_core.studies.report import load_run, run_figures
    rep = run_figures(load_run(rec1), SpacecraftParams().orbit_period)
    assert rep["truth_samples"] == STEPS + 1
    for key in ("final_dq", "peak_dq", "rms_dq", "peak_m"):
        assert rep[key] == pytest.approx(run.figures[key], rel=1e-12), key
    _check_tf_and_markers(rec1)
    original = _dipoles(rec1)
    assert len(original) >= 0.5 * STEPS, "SIL recording lacks dipole commands"

    procs = Procs(ros_env(), tmp_path / "replay_logs")
    rec2 = tmp_path / "replayed"
    try:
        rec = procs.start("recorder", executable("recorder") + [
            "-o", str(rec2), "--topics", f"{DIPOLE}:geometry_msgs/msg/Vector3Stamped"])
        procs.wait_for_line(rec, "magtune-recorder ready")
        procs.start("controller", executable("controller") + [
            "--ros-args", "--params-file", str(scenario.DEFAULT_SPACECRAFT), "--params-file",
            str(gains), "-p", "use_sim_time:=true"])
        time.sleep(1.5)  # let the recorder discover the controller's publisher
        ply = procs.start("player", executable("player") + [
            str(rec1), "--topics", MAG, ATTITUDE, "--rate", "25", "--wait-subscribers", "30"])  # field first at a tie
        assert ply.wait(90) == 0, procs.output(ply)
        time.sleep(1.0)
        rec.send_signal(2)
        assert rec.wait(30) == 0, procs.output(rec)
    finally:
        procs.stop_all()
    replayed = _dipoles(rec2)
    common = sorted(set(original) & set(replayed))
    assert len(common) >= 0.9 * len(original)
    a = np.array([original[s] for s in common])
    b = np.array([replayed[s] for s in common])
    np.testing.assert_allclose(b, a, rtol=1e-12, atol=0.0)
    assert np.abs(a).max() > 0.1  # the comparison is about real commands, not zeros


def _check_tf_and_markers(path):
    """/tf: one tf2_msgs/TFMessage per step, orbital -> body with the rotation of sim/truth (the
    same quaternion, bit for bit); its type hash is rosbags' own for ROS 2 Jazzy's tf2_msgs (so
    the vendored package is wire-identical); sim/markers: field arrow along the true field."""
    from rosbags.typesys import Stores, get_typestore

    topics = bag.topics_of(path)
    assert topics[TF].type == "tf2_msgs/msg/TFMessage" and topics[TF].message_count == STEPS + 1
    assert topics[TF].type_description_hash == get_typestore(Stores.ROS2_JAZZY).hash_rihs01("tf2_msgs/msg/TFMessage")
    d = Decoder()
    truth, tf, field, arrow = {}, {}, {}, {}
    for m in bag.iter_messages(path, topics=[TF, TRUTH, MARKERS, "/sim/magnetic_field"]):
        o = d.decode(m.data, m.type)
        if m.topic == TF:
            (t,) = o.transforms
            assert (t.header.frame_id, t.child_frame_id) == (FRAME_ORBITAL, FRAME_BODY)
            r = t.transform.rotation
            tf[stamp_ns(t)] = (r.w, r.x, r.y, r.z)
        elif m.topic == TRUTH:
            r = o.pose.pose.orientation
            truth[stamp_ns(o)] = (r.w, r.x, r.y, r.z)
        elif m.topic == MARKERS:
            f = o.markers[1]
            assert f.header.frame_id == FRAME_BODY and f.ns == "magnetic_field"
            arrow[stamp_ns(f)] = np.array([f.points[1].x, f.points[1].y, f.points[1].z])
        else:
            b = o.magnetic_field
            field[stamp_ns(o)] = np.array([b.x, b.y, b.z])
    assert tf == truth
    common = sorted(set(arrow) & set(field))
    assert len(common) >= STEPS
    for s in common:   # 0.05 m per uT (simulator.MARKER_FIELD_SCALE); 1e-12: one float multiply
        np.testing.assert_allclose(arrow[s], field[s] * 0.05e6, rtol=1e-12)
