"""Bag benchmarks: recorder throughput with zero loss, replay throughput at rate 0, bag size.

``python bench/bag_throughput.py [--steps 4000] [--sil-steps 600] [--json]`` (after
``. scripts/env.sh``). Real DDS (Fast DDS, separate processes), real MCAP files.

1. writer only: :class:`magtune_core.bags.BagWriter` in-process (upper bound, no DDS);
2. recorder: tests/support/bag_fixture_pub.py publishes ``--steps`` steps of 5-6 messages (Imu,
   MagneticField, Vector3Stamped, Odometry, Clock, DiagnosticArray) as fast as it can; the
   recorder must record all of them; msgs/s and MB/s (CDR payload) over the publisher's wall
   time; a second run adds a ``--blob``-byte UInt8MultiArray per step (MB/s with big messages);
3. player at rate 0 into a subscriber (tests/support/bag_fixture_sub.py) and with no subscriber;
4. bag size per orbit: a short ``magtune sil --bag`` run (simulator + sensors + controller
   at 1 Hz) extrapolated to T = 5614.8 s, and the CDR payload per step for comparison.
"""
from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "tests" / "support"))

import bag_fixture_pub as fx  # noqa: E402
from bagproc import Procs, executable, ros_env  # noqa: E402

from magtune_core import bags as bag  # noqa: E402


def payload_bytes(path) -> int:
    return sum(len(m.data) for m in bag.iter_messages(path))


def bench_writer(tmp: Path, n: int = 20000) -> dict:
    data = bytes(300)
    w = bag.BagWriter(tmp / "writer_only")
    w.add_topic("/imu", "sensor_msgs/msg/Imu")
    t0 = time.perf_counter()
    for i in range(n):
        w.write("/imu", data, i * 1000)
    w.close()
    dt = time.perf_counter() - t0
    return {"messages": n, "msg_per_s": n / dt, "MB_per_s": n * len(data) / dt / 1e6}


def bench_recorder(tmp: Path, steps: int, blob: int = 0) -> dict:
    procs = Procs(ros_env(), tmp / f"logs_rec{blob}")
    out = tmp / f"rec{blob}"
    topics = [f"{t}:{ty}" for t, ty in fx.TOPICS.items()]
    if blob:
        topics.append("/blob:std_msgs/msg/UInt8MultiArray")
    try:
        rec = procs.start("recorder", executable("recorder") + ["-o", str(out), "--topics", *topics])
        procs.wait_for_line(rec, "magtune-recorder ready")
        pub = procs.python("publisher", "bag_fixture_pub.py", steps, "--blob", blob)
        pub.wait(300)
        line = [x for x in procs.output(pub).splitlines() if x.startswith("published")][-1]
        wall = float(line.split(" in ")[1].split()[0])
        time.sleep(0.5)
        rec.send_signal(2)
        rec.wait(60)
        summary = json.loads(procs.output(rec).strip().splitlines()[-1])
    finally:
        procs.stop_all()
    expected = fx.counts(steps)
    if blob:
        expected["/blob"] = steps
    n = sum(expected.values())
    nbytes = payload_bytes(out)
    return {"published": n, "recorded": summary["messages"],
            "lost": n - summary["messages"], "per_topic_ok": summary["per_topic"] == expected,
            "publisher_wall_s": wall, "msg_per_s": n / wall, "MB_per_s": nbytes / wall / 1e6,
            "payload_MB": nbytes / 1e6, "file_MB": bag.resolve_mcap(out).stat().st_size / 1e6,
            "bag": str(out)}


def bench_player(tmp: Path, bag_dir: Path, n_data: int) -> dict:
    res = {}
    procs = Procs(ros_env(), tmp / "logs_play")
    try:
        ply = procs.start("player_nosub", executable("player") + [str(bag_dir), "--rate", "0"])
        ply.wait(120)
        rep = json.loads(procs.output(ply).strip().splitlines()[-1])
        total = sum(v for k, v in rep["published"].items() if k != "/clock")
        res["no_subscriber"] = {"messages": total, "wall_s": rep["wall_s"],
                                "msg_per_s": total / rep["wall_s"]}
        sub = procs.python("subscriber", "bag_fixture_sub.py", tmp / "sub.json",
                           "--expect", n_data, "--timeout", 120)
        procs.wait_for_line(sub, "subscriber ready")
        t0 = time.monotonic()
        ply = procs.start("player_sub", executable("player") + [
            str(bag_dir), "--rate", "0", "--wait-subscribers", "20",
            "--topics", "/imu", "/magnetic_field", "/dipole_command", "/truth"])
        ply.wait(180)
        sub.wait(180)
        t_sub = time.monotonic() - t0
        rep = json.loads(procs.output(ply).strip().splitlines()[-1])
        got = json.loads((tmp / "sub.json").read_text())
        received = sum(len(v) for k, v in got.items() if k.startswith("/"))
        res["into_subscriber"] = {"messages": n_data, "received": received,
                                  "player_wall_s": rep["wall_s"],
                                  "player_msg_per_s": n_data / rep["wall_s"],
                                  "until_all_received_s": t_sub,
                                  "end_to_end_msg_per_s": received / t_sub}
    finally:
        procs.stop_all()
    return res


def bench_size(tmp: Path, sil_steps: int) -> dict:
    from magtune_core.design.gains import save_gains
    from magtune_core.design.lq import lq_gains
    from magtune_core.design.model import AttitudeLTP
    from magtune_core.design.params import SpacecraftParams
    from magtune_core.ros.sil import run_sil
    p = SpacecraftParams()
    gains = tmp / "sigma_60.yaml"
    save_gains(gains, lq_gains(AttitudeLTP.from_params(p), 60.0, 1.0))
    out = tmp / "sil"
    run = run_sil(gains, steps=sil_steps, bag=out, log_dir=tmp / "sil_logs", timeout=300)
    inf = bag.info(out)
    size = bag.resolve_mcap(out).stat().st_size
    payload = payload_bytes(out)
    per_s = size / inf["duration_s"]
    return {"sim_seconds": inf["duration_s"], "messages": inf["message_count"],
            "file_bytes": size, "payload_bytes": payload,
            "compression_ratio": payload / size,
            "payload_bytes_per_step": payload / (sil_steps + 1),
            "MB_per_orbit_file": per_s * p.orbit_period / 1e6,
            "MB_per_orbit_payload": payload / inf["duration_s"] * p.orbit_period / 1e6,
            "sil_real_time_factor": run.real_time_factor,
            "topics": {k: v["count"] for k, v in inf["topics"].items()}}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=4000)
    ap.add_argument("--sil-steps", type=int, default=600)
    ap.add_argument("--blob", type=int, default=65536, help="large-message run: bytes per /blob")
    ap.add_argument("--blob-steps", type=int, default=1000)
    ap.add_argument("--json", action="store_true")
    a = ap.parse_args(argv)
    with tempfile.TemporaryDirectory(prefix="magtune_bench_") as d:
        tmp = Path(d)
        res = {"writer_only": bench_writer(tmp)}
        res["recorder"] = bench_recorder(tmp, a.steps)
        res["recorder_large"] = bench_recorder(tmp, a.blob_steps, a.blob)
        res["player_rate0"] = bench_player(tmp, Path(res["recorder"]["bag"]), 4 * a.steps)
        res["bag_size"] = bench_size(tmp, a.sil_steps)
    if a.json:
        print(json.dumps(res, indent=1))
        return 0
    w, r, p, s = res["writer_only"], res["recorder"], res["player_rate0"], res["bag_size"]
    print(f"writer only      : {w['msg_per_s']:9.0f} msg/s  {w['MB_per_s']:6.2f} MB/s (300 B msgs)")
    print(f"recorder (DDS)   : {r['msg_per_s']:9.0f} msg/s  {r['MB_per_s']:6.2f} MB/s, "
          f"{r['recorded']}/{r['published']} recorded (lost {r['lost']}), file {r['file_MB']:.2f} MB "
          f"for {r['payload_MB']:.2f} MB CDR")
    rl = res["recorder_large"]
    print(f"recorder (large) : {rl['msg_per_s']:9.0f} msg/s  {rl['MB_per_s']:6.2f} MB/s with {a.blob} B "
          f"/blob per step, {rl['recorded']}/{rl['published']} recorded (lost {rl['lost']})")
    ns, isub = p["no_subscriber"], p["into_subscriber"]
    print(f"player rate 0    : {ns['msg_per_s']:9.0f} msg/s without subscriber; into a Python "
          f"subscriber {isub['received']}/{isub['messages']} received, "
          f"{isub['end_to_end_msg_per_s']:.0f} msg/s end to end")
    print(f"bag size         : {s['MB_per_orbit_file']:.2f} MB/orbit on disk (zstd), "
          f"{s['MB_per_orbit_payload']:.2f} MB/orbit CDR; {s['payload_bytes_per_step']:.0f} B CDR "
          f"per 1 Hz step; compression x{s['compression_ratio']:.2f} "
          f"(SIL {s['sim_seconds']:.0f} s sim at {s['sil_real_time_factor']:.0f}x real time)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
