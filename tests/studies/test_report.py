"""``magtune report`` on synthetic bags with known signals (no ROS processes).

Each bag holds /sim/truth with q = [cos(a/2), sin(a/2) e] (so |dq_R| = sin(a/2) exactly) and
a dipole |m| = c(t); figures of merit are compared with the same formulas evaluated directly.
"""
from __future__ import annotations

import json

import numpy as np
import pytest

from magtune_core import bags as bag
from magtune_core.bags.decode import Decoder
from magtune_core.base.topics import DIPOLE, TRUTH
from magtune_core.cli import main as cli_main
from magtune_core.studies import report

T = 600.0  # short "orbit" so a 5-orbit run stays small


def _make(tmp_path, name, sigma, n=3001, dt=1.0, forged=(), **split):
    """A bag of ``n`` truth and dipole samples; ``forged``: (t, (x, y, z)) dipole commands written after them
    (what a peer publishing on the dipole topic leaves in a recording)."""
    d = Decoder()
    Ty = d.types()
    w = bag.BagWriter(tmp_path / name, custom_data={"sigma": sigma}, **split)
    w.add_topic(TRUTH, "nav_msgs/msg/Odometry")
    w.add_topic(DIPOLE, "geometry_msgs/msg/Vector3Stamped")
    e = np.array([1.0, 2.0, 2.0]) / 3.0
    tau = 100.0 * sigma / 60.0
    for k in range(n):
        t = k * dt
        a = 0.1 * np.exp(-t / tau)
        sec, nsec = divmod(int(round(t * 1e9)), 10**9)
        st = Ty["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec)
        hdr = Ty["std_msgs/msg/Header"](stamp=st, frame_id="orbital")
        qv = np.sin(a / 2) * e
        od = Ty["nav_msgs/msg/Odometry"](
            header=hdr, child_frame_id="body",
            pose=Ty["geometry_msgs/msg/PoseWithCovariance"](
                pose=Ty["geometry_msgs/msg/Pose"](
                    position=Ty["geometry_msgs/msg/Point"](x=0.0, y=0.0, z=0.0),
                    orientation=Ty["geometry_msgs/msg/Quaternion"](
                        x=qv[0], y=qv[1], z=qv[2], w=np.cos(a / 2))),
                covariance=np.zeros(36)),
            twist=Ty["geometry_msgs/msg/TwistWithCovariance"](
                twist=Ty["geometry_msgs/msg/Twist"](
                    linear=Ty["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
                    angular=Ty["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=-2 * np.pi / T)),
                covariance=np.zeros(36)))
        w.write(TRUTH, d.encode(od, "nav_msgs/msg/Odometry"), int(round(t * 1e9)))
        m = Ty["geometry_msgs/msg/Vector3Stamped"](
            header=hdr, vector=Ty["geometry_msgs/msg/Vector3"](x=3.0 * a / 0.1, y=0.0, z=4.0 * a / 0.1))
        w.write(DIPOLE, d.encode(m, "geometry_msgs/msg/Vector3Stamped"), int(round(t * 1e9)))
    for t, (x, y, z) in forged:
        sec, nsec = divmod(int(round(t * 1e9)), 10**9)
        hdr = Ty["std_msgs/msg/Header"](stamp=Ty["builtin_interfaces/msg/Time"](sec=sec, nanosec=nsec), frame_id="body")
        m = Ty["geometry_msgs/msg/Vector3Stamped"](header=hdr, vector=Ty["geometry_msgs/msg/Vector3"](x=x, y=y, z=z))
        w.write(DIPOLE, d.encode(m, "geometry_msgs/msg/Vector3Stamped"), int(round((n - 1) * dt * 1e9)))
    w.close()
    t = np.arange(n) * dt
    a = 0.1 * np.exp(-t / tau)
    return tmp_path / name, t, np.sin(a / 2), 5.0 * a / 0.1


def test_report_figures_and_summary(tmp_path):
    bags = [_make(tmp_path, f"s{s}", s) for s in (60, 120, 240)]
    out = tmp_path / "rep"
    rc = cli_main(["report", *(str(b[0]) for b in bags), "--out", str(out), "--orbit-period", str(T)])
    assert rc == 0
    for f in ("fig2_first_orbit.png", "fig3_orbits_2_5.png", "fig4_quaternion.png",
              "fig5_rates_dipoles.png", "summary.md"):
        assert (out / f).stat().st_size > 500, f
    assert (out / "fig2_first_orbit.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    s = json.loads((out / "summary.json").read_text())
    for (path, t, dq, mn), sig in zip(bags, (60, 120, 240)):
        r = s[path.name]
        assert r["label"] == f"sigma = {sig}"
        sel = (t >= T) & (t <= 5 * T)
        # CDR keeps float64 exactly; only the sign/normalization arithmetic differs: 1e-12
        assert r["final_dq"] == pytest.approx(dq[-1], rel=1e-12)
        assert r["peak_dq"] == pytest.approx(dq.max(), rel=1e-12)
        assert r["rms_dq"] == pytest.approx(np.sqrt(np.mean(dq[sel] ** 2)), rel=1e-12)
        assert r["peak_m"] == pytest.approx(mn.max(), rel=1e-12)
        assert r["orbits"] == pytest.approx(5.0)
        assert r["integrity"] == {"complete": True}
    md = (out / "summary.md").read_text()
    assert "| s60 | sigma = 60 |" in md and "Figs. 4-5: s60, s120, s240" in md


def test_report_on_damaged_bag_says_so(tmp_path):
    path, *_ = _make(tmp_path, "cut", 60, n=1500)
    f = bag.resolve_mcap(path)
    data = f.read_bytes()
    f.write_bytes(data[: int(len(data) * 0.7)])
    s = report.make_report([path], tmp_path / "rep", orbit_period=T)
    integ = s["cut"]["integrity"]
    assert integ["complete"] is False and 0 < integ["messages_recovered"] < 3000
    assert "damaged" in (tmp_path / "rep" / "summary.md").read_text()


def test_report_on_split_bag_names_missing_and_damaged_files(tmp_path, capsys):
    """Why: a split bag's missing or damaged later file was skipped and the bag called complete."""
    path, *_ = _make(tmp_path, "split", 60, n=1500, max_duration_ns=500 * 10**9)
    files = bag.resolve_mcaps(path)
    assert len(files) == 3
    files[2].unlink()
    files[1].write_bytes(files[1].read_bytes()[:2000])
    out = tmp_path / "rep"
    assert cli_main(["report", str(path), "--out", str(out), "--orbit-period", str(T)]) == 0
    err = capsys.readouterr().err
    integ = json.loads((out / "summary.json").read_text())["split"]["integrity"]
    assert integ["complete"] is False and integ["missing_files"] == ["split_2.mcap"]
    assert integ["metadata_message_count"] == 3000 and integ["messages_recovered"] < 2000
    assert "missing file(s) split_2.mcap; metadata.yaml says 3000 msgs" in (out / "summary.md").read_text()
    assert "warning: split: split_2.mcap: listed in metadata.yaml but missing" in err
    assert "warning: split: split_1.mcap: " in err


def test_report_errors_are_one_line(tmp_path, capsys):
    empty = tmp_path / "empty"
    w = bag.BagWriter(empty)
    w.add_topic("/other", "std_msgs/msg/String")
    w.close()
    assert cli_main(["report", str(empty), "--out", str(tmp_path / "r")]) == 1
    assert "no messages on /sim/truth" in capsys.readouterr().err


def test_report_degrees_html_and_small_multiples(tmp_path):
    """Pointing error in degrees (2 asin |dq_R|, checked against the bag's known signal), every
    run in Figs. 4-5, and report.html: one file, figures inlined, the summary table inside."""
    bags = [_make(tmp_path, f"s{s}", s, n=1301) for s in (60, 240)]
    out = tmp_path / "rep"
    s = report.make_report([b[0] for b in bags], out, orbit_period=T)
    for path, t, dq, _ in bags:
        r = s[path.name]
        deg = np.degrees(2 * np.arcsin(dq))  # the angle the test bag's quaternion rotates by
        assert r["final_deg"] == pytest.approx(deg[-1], rel=1e-9)
        assert r["peak_deg"] == pytest.approx(deg.max(), rel=1e-9)
        sel = (t >= T) & (t <= 5 * T)
        assert r["rms_deg"] == pytest.approx(np.sqrt(np.mean(deg[sel] ** 2)), rel=1e-9)
        assert r["peak_deg"] == pytest.approx(np.degrees(0.1), rel=1e-9)  # a(0) = 0.1 rad
    page = (out / "report.html").read_text()
    assert page.count('src="data:image/png;base64,') == 4  # Figs. 2-5, nothing external
    assert "src=\"http" not in page and "<script" not in page
    assert "<td>s60</td>" in page and "<td>sigma = 240</td>" in page
    md = (out / "summary.md").read_text()
    assert "Figs. 4-5: s60, s240" in md and "pointing [deg]" in md
    # small multiples: Fig. 4 has one row per run, so the image grows with the number of runs
    from matplotlib.image import imread
    h2 = imread(out / "fig4_quaternion.png").shape[0]
    report.make_report([bags[0][0]], tmp_path / "one", orbit_period=T)
    assert h2 > 1.5 * imread(tmp_path / "one" / "fig4_quaternion.png").shape[0]


@pytest.mark.parametrize("n, fig3", [(601, False), (301, False), (900, True)])
def test_report_short_runs_state_their_windows(tmp_path, n, fig3):
    """A run of one orbit or less: no (empty) Fig. 3, the windows are stated, the RMS is over the
    whole run rather than one sample; 1.5 orbits: Fig. 3 covers orbit 1 to the end."""
    path, t, dq, mn = _make(tmp_path, "short", 60, n=n)
    out = tmp_path / "rep"
    (out).mkdir()
    (out / "fig3_orbits_2_5.png").write_bytes(b"stale")
    s = report.make_report([path], out, orbit_period=T)["short"]
    md = (out / "summary.md").read_text()
    assert (out / "fig3_orbits_2_5.png").exists() is fig3
    if fig3:
        assert "Fig. 3: t = 1.00-1.50 orbits" in md
        assert s["rms_window"] == (T, t[-1])
    else:
        assert "Fig. 3 not drawn: no run is longer than one orbit" in md
        assert s["rms_window"] == (0.0, t[-1])  # whole run, stated
        assert s["rms_dq"] == pytest.approx(np.sqrt(np.mean(dq ** 2)), rel=1e-12)
        assert s["rms_m"] == pytest.approx(np.sqrt(np.mean(mn ** 2)), rel=1e-12)
        assert np.isnan(s["rms_m_orbits_2_5"])  # not a one-sample RMS
    assert f"| {s['rms_window'][0]:.0f}-{s['rms_window'][1]:.0f} |" in md


def test_report_leaves_out_dipole_commands_the_simulator_rejects(tmp_path):
    """Issue 45: nan commands a peer published (the simulator rejects them) made peak abs(m) nan and the bag
    was called complete. Now: the figures come from the commands flown, and the summary counts the others."""
    forged = [(100.5, (float("nan"), 0.0, 0.0)), (200.5, (float("inf"), 1.0, 1.0)), (300.5, (0.0, -1e6, 0.0))]
    path, t, dq, mn = _make(tmp_path, "forged", 60, n=1301, forged=forged)
    clean, *_ = _make(tmp_path, "clean", 60, n=1301)
    out = tmp_path / "rep"
    assert cli_main(["report", str(path), str(clean), "--out", str(out), "--orbit-period", str(T)]) == 0
    s = json.loads((out / "summary.json").read_text())
    r, c = s["forged"], s["clean"]
    assert r["peak_m"] == pytest.approx(mn.max(), rel=1e-12) and r["peak_m"] == c["peak_m"]
    assert r["rms_m"] == c["rms_m"] and np.isfinite(r["rms_m"]) and r["dipole_samples"] == len(t)
    assert (r["dipole_commands_rejected"], r["dipole_commands_beyond_limit"]) == (2, 1)
    assert (c["dipole_commands_rejected"], c["dipole_commands_beyond_limit"]) == (0, 0)
    note = ("2 dipole commands rejected by the simulator (non-finite); 1 dipole command beyond the per-axis "
            "limit +-50 A m^2 (the simulator flies at most the limit); left out of abs(m) and the figures")
    assert r["integrity"] == {"complete": True, "note": note} and c["integrity"] == {"complete": True}
    md = (out / "summary.md").read_text()
    assert f"| files complete; {note} |" in md and f"forged: {note}." in md and "| complete |" in md
    assert "nan" not in md.split("| bag |")[1].split("\n\n")[0]  # no nan in the table
    assert note in (out / "report.html").read_text()
