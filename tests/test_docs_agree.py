"""Docs and code agree: the QoS depths the package README states are the code's, every file names
the orbital Z axis the same way (X nadir, Y along-track, Z = X x Y = -orbit normal), the README is
a short guide whose tour runs real subcommands and options, no page reads as a diary of numbered
passes, every relative link and quoted path resolves, and the figures quoted in the docs equal the
files they come from (gains provenance, docs/sampling.json). Reading files only: no numerics."""
from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
PKG = ROOT / "ros2_ws" / "src" / "magtune_ros"


def test_readme_qos_depths_are_the_code_s():
    code = (PKG / "magtune_ros" / "qos.py").read_text()
    depth = {name: int(d) for name, d in re.findall(r"^(\w+_QOS) = QoSProfile\([^)]*?depth=(\d+)", code, re.M | re.S)}
    assert set(depth) >= {"LOCKSTEP_QOS", "CLOCK_QOS", "DIAG_QOS"}, depth
    readme = (PKG / "README.md").read_text()
    stated = {name: int(d) for d, name in re.findall(r"KEEP_LAST (\d+)\s*\(`(\w+_QOS)`", readme)}
    assert stated == {k: depth[k] for k in ("LOCKSTEP_QOS", "CLOCK_QOS", "DIAG_QOS")}, stated


def _project_files():
    for sub in ("README.md", "docs", "magtune_core", "ros2_ws/src", "config", "bags/README.md"):
        path = ROOT / sub
        files = [path] if path.is_file() else [*path.rglob("*.py"), *path.rglob("*.md"), *path.rglob("*.yaml")]
        yield from (f for f in files if "__pycache__" not in f.parts)


def test_orbital_z_is_minus_orbit_normal_everywhere():
    """A Z axis called the orbit normal must carry the minus sign (or say 'minus'/'opposite')."""
    bad = []
    for f in _project_files():
        text = " ".join(f.read_text(errors="replace").split())
        for m in re.finditer(r"\bZ\b[^.;\n]{0,12}?orbit[ -]normal", text):
            if not re.search(r"(-|minus|opposite|anti)\s*(the\s+)?orbit[ -]normal", m.group(0)):
                bad.append(f"{f.relative_to(ROOT)}: ...{m.group(0)}...")
    assert not bad, bad


# --- the user guide and the reference pages -------------------------------------------------------

README = ROOT / "README.md"


def _guide_pages():
    """README.md, every docs page and bench/README.md: the pages a user reads."""
    return [README, *sorted((ROOT / "docs").glob("*.md")), ROOT / "bench" / "README.md"]


def _strip_code(text):
    """Text without fenced code blocks (whose brackets are not links)."""
    return re.sub(r"^```.*?^```", "", text, flags=re.M | re.S)


def _code_blocks(text):
    return re.findall(r"^```[^\n]*\n(.*?)^```", text, flags=re.M | re.S)


def _section(text, heading):
    """The body of the markdown section whose heading line is ``heading``, up to the next heading of
    the same or a higher level (lines inside fenced code blocks are not headings)."""
    level = len(heading) - len(heading.lstrip("#"))
    body, inside, fenced = [], False, False
    for line in text.splitlines():
        if line.startswith("```"):
            fenced = not fenced
        elif not fenced and re.match(r"#{1,%d} " % level, line):
            if inside:
                break
            inside = line.strip() == heading
            continue
        if inside:
            body.append(line)
    assert body, f"no section {heading!r}"
    return "\n".join(body) + "\n"


def _table_rows(text):
    """Cells of every markdown table row that is not a header separator."""
    rows = []
    for line in text.splitlines():
        if line.startswith("|") and not re.match(r"^\|[-| :]+\|$", line):
            rows.append([c.strip() for c in line.strip().strip("|").split("|")])
    return rows


def test_readme_is_a_short_guide_with_the_two_commands_first():
    text = README.read_text()
    assert len(text.splitlines()) <= 300, len(text.splitlines())
    first = _code_blocks(text)[0]
    assert "bash scripts/demo.sh" in first and "bash scripts/test.sh" in first, first


NUMBERED_PASS = re.compile(
    r"\b(first|second|third|fourth|fifth|sixth|seventh|eighth|ninth|tenth|eleventh|twelfth|thirteenth"
    r"|fourteenth|fifteenth|\d+(st|nd|rd|th))[- ]pass(es)?\b|\bpass(es)? (\d+|#\d+)\b|\bissue #?\d+,? pass\b",
    re.I)


def test_no_page_refers_to_numbered_passes():
    """The guide and the reference pages are reference, not a diary (history: docs/decisions.md)."""
    pages = [*_guide_pages(), *sorted((ROOT / "docs").glob("*.txt"))]  # sampling_conclusion.txt feeds sampling.md
    bad = [f"{p.relative_to(ROOT)}:{i}: {m.group(0)}"
           for p in pages for i, line in enumerate(p.read_text().splitlines(), 1)
           for m in NUMBERED_PASS.finditer(line)]
    assert not bad, bad


def test_numbered_pass_pattern_catches_what_it_should():
    for s in ("ninth pass", "the twelfth-pass gains", "Pass 12", "3rd pass", "issue 9, pass"):
        assert NUMBERED_PASS.search(s), s
    for s in ("a passing level", "the gamma-test passes", "bypass 2 steps", "passed 12 tests"):
        assert not NUMBERED_PASS.search(s), s


def _slug(heading):
    """GitHub's anchor of a markdown heading."""
    s = re.sub(r"[^\w\- ]", "", heading.strip().lower())
    return s.replace(" ", "-")


def _anchors(path):
    seen, out = {}, set()
    for h in re.findall(r"^#{1,6} (.+)$", _strip_code(path.read_text()), flags=re.M):
        s = _slug(h)
        n = seen.get(s, 0)
        out.add(s if n == 0 else f"{s}-{n}")
        seen[s] = n + 1
    return out


def test_every_relative_link_resolves():
    """Every relative link of the guide pages names an existing file, and an anchor into a markdown
    page names one of its headings."""
    bad = []
    for page in _guide_pages():
        for target in re.findall(r"\]\(([^)\s]+)\)", _strip_code(page.read_text())):
            if re.match(r"^[a-z]+:", target):  # http:, https:, mailto:
                continue
            path, _, anchor = target.partition("#")
            dest = (page.parent / path).resolve() if path else page
            if not dest.exists():
                bad.append(f"{page.relative_to(ROOT)}: {target} (no such file)")
            elif anchor and dest.suffix == ".md" and anchor not in _anchors(dest):
                bad.append(f"{page.relative_to(ROOT)}: {target} (no such heading)")
    assert not bad, bad


def _gains_figures(path):
    from magtune_core.base.paramfile import read_ros_params

    return read_ros_params(ROOT / path, "controller")


def test_shipped_gains_table_is_the_files():
    """docs/tuning.md "Shipped gains" (the canonical table of the shipped J, c1, c2, rho) quotes the
    provenance of each gains file; the generated docs/table1.md quotes the same J."""
    rows = _table_rows(_section((ROOT / "docs" / "tuning.md").read_text(), "## Shipped gains"))
    quoted = {}
    for cells in rows[1:]:
        path = re.search(r"\]\(\.\./([^)]+)\)", cells[0]).group(1)
        quoted[path] = cells
    expected = {f"config/gains/{d}sigma_{s}.yaml" for d in ("", "paper_method/") for s in (60, 120, 240)}
    assert set(quoted) == expected, sorted(quoted)
    for path, (_, sigma, J, c1, c2, rho, _margin) in quoted.items():
        p = _gains_figures(path)
        assert float(sigma) == p["sigma"], path
        assert J == f"{p['J']:.2f}" and c1 == f"{p['c1']:.2f}", (path, J, c1, p["J"], p["c1"])
        assert int(c2) == round(p["c2"]) and rho == f"{p['rho']:.2e}", (path, c2, rho, p["c2"], p["rho"])
    table1 = {(r[0], r[1]): r[2] for r in _table_rows((ROOT / "docs" / "table1.md").read_text())
              if len(r) > 3 and r[1] in ("cma", "paper")}
    for s in (60, 120, 240):
        for method, d in (("cma", ""), ("paper", "paper_method/")):
            assert table1[(str(s), method)] == f"{_gains_figures(f'config/gains/{d}sigma_{s}.yaml')['J']:.2f}"
    # the status table of table1.md's notes names the shipped J too
    notes = _table_rows(_section((ROOT / "docs" / "table1.md").read_text(), "## What the shipped gains are"))
    for cells in notes[1:]:
        assert cells[1] == f"{_gains_figures(f'config/gains/sigma_{cells[0]}.yaml')['J']:.2f}", cells


def test_example_12u_design_figures_are_the_gains_file_s():
    p = _gains_figures("config/examples/cubesat12u/gains_sigma120.yaml")
    rho = re.sub(r"e([-+])0*(\d)", r"e\1\2", f"{p['rho']:.1e}").replace("e+", "e")  # 2.1e-3, as written
    design = f"J = {p['J']:.0f}, c1 = {p['c1']:.0f}, c2 = {p['c2']:.0f}, rho = {rho}"
    assert f"| design (LTP, 128 Magnus steps, resolved) | {design} |" in (ROOT / "docs" / "own_satellite.md").read_text()
    nominal = f"{p['J']:.0f} / {p['c1']:.0f} / {p['c2']:.0f} / {rho}"
    robust = (ROOT / "docs" / "robust.md").read_text()
    assert f"| nominal (`gains_sigma120.yaml`) | {nominal} |" in robust, nominal  # the analysis table


def test_sampling_table_is_sampling_json():
    """docs/sampling.md's table shows the rows of docs/sampling.json, and its verdict ends with the
    hand-kept conclusion docs/sampling_conclusion.txt verbatim (as `magtune sampling --conclusion
    @FILE` writes it)."""
    import json

    text = (ROOT / "docs" / "sampling.md").read_text()
    rows = json.loads((ROOT / "docs" / "sampling.json").read_text())["rows"]
    study = text.split("## The paper's claim")[0]  # the conclusion may hold tables of its own
    table = [r for r in _table_rows(study) if r[0] != "sigma"]
    assert len(table) == len(rows) > 0
    for cells, r in zip(table, rows):
        assert cells[:4] == [f"{r['sigma']:g}", f"{r['ts']:g}", f"{r['rms_dq']:.4e}", f"{r['peak_m']:.3f}"], cells
        assert cells[6:] == [f"{r['peak_dq']:.4e}", str(r["saturated_steps"])], cells
    conclusion = (ROOT / "docs" / "sampling_conclusion.txt").read_text().strip()
    assert text.rstrip().endswith(conclusion)


def _help(*argv):
    """``magtune ARGV --help`` in this process (the console script's entry point)."""
    import contextlib
    import io

    from magtune_core.cli import main

    out = io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.suppress(SystemExit):
        main([*argv, "--help"])
    return out.getvalue()


def test_readme_tour_uses_real_subcommands_and_options():
    tour = "\n".join(_code_blocks(_section(README.read_text(), "## A 5-minute tour")))
    tour = re.sub(r"#.*", "", tour)  # comments
    commands = re.findall(r"^magtune ([\w-]+)( (?:info|recover)\b)?(.*)$", tour, flags=re.M)
    listed = set(re.findall(r"^    ([a-z][\w-]*)", _help().split("options:")[0], flags=re.M))
    assert {"tune", "analyze", "sil", "replay", "report", "campaign", "campaign-report"} <= listed, listed
    used = {c for c, _, _ in commands}
    assert {"tune", "analyze", "sil", "replay", "report", "campaign"} <= used, used
    helps = {}
    for cmd, sub, rest in commands:
        assert cmd in listed, f"magtune {cmd}: not a subcommand"
        argv = (cmd, *sub.split())
        text = helps.setdefault(argv, _help(*argv))
        assert text.startswith("usage:"), argv
        for flag in re.findall(r"(?<![\w-])--[\w-]+", rest):
            assert re.search(rf"(?<![\w-]){flag}\b", text), f"magtune {' '.join(argv)}: no option {flag}"


def test_quoted_repository_paths_exist():
    """A path the guide pages quote in backticks (`config/...`, `tests/...`, `bench/...`, `scripts/...`,
    `bags/...`, `docs/...`) exists; placeholders (NAME, *, {..}, <..>) are skipped. Paths inside
    magtune_core/ are left to docs/architecture.md and tests/test_architecture.py."""
    bad = []
    for page in _guide_pages():
        for quoted in re.findall(r"`((?:config|scripts|bench|bags|tests|docs)/[^`\s:]*)", page.read_text()):
            path = quoted.rstrip("/.,")
            if re.search(r"[*{<]|NAME|NNNNN", path):
                continue
            if not (ROOT / path).exists():
                bad.append(f"{page.relative_to(ROOT)}: {quoted}")
    assert not bad, bad


OWN_SATELLITE = ROOT / "docs" / "own_satellite.md"
WALKTHROUGH = "### Walk-through: the 12U from its TLE and hardware file"


def _magtune_lines(text):
    """The ``magtune`` command lines of the fenced code blocks of ``text``, shell-split, comments dropped."""
    import shlex

    lines = "\n".join(_code_blocks(text)).splitlines()
    return [shlex.split(line, comments=True) for line in lines if line.startswith("magtune ")]


def _parse(argv):
    """``magtune ARGV`` through the CLI's own parser (nothing runs): the namespace, or an assertion
    naming the line argparse refuses."""
    import contextlib
    import io

    from magtune_core.cli import build_parser

    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err):
            return build_parser().parse_args(argv)
    except SystemExit:
        raise AssertionError(f"magtune {' '.join(argv)}: {err.getvalue().strip().splitlines()[-1]}") from None


def test_own_satellite_commands_parse_and_name_existing_files():
    """Every ``magtune`` line of docs/own_satellite.md's code blocks is accepted by the CLI parser
    (subcommand, options, their values' types), and every repository file it names exists."""
    commands = _magtune_lines(OWN_SATELLITE.read_text())
    assert len(commands) >= 10, commands
    bad = []
    helps = {}
    for argv in commands:
        a = _parse(argv[1:])
        at = argv.index(a.command)  # options before it are the global parser's
        for flags, text in ((argv[1:at], helps.setdefault("", _help())),
                            (argv[at + 1:], helps.setdefault(a.command, _help(a.command)))):
            # written in full (argparse would take an abbreviation such as --run for --runs)
            bad += [f"magtune {a.command}: {f} is not an option's full name" for f in flags
                    if f.startswith("--") and not re.search(rf"(?<![\w-]){re.escape(f)}(?![\w-])", text)]
        bad += [f"magtune {' '.join(argv[1:3])} ...: {a}" for a in argv
                if re.match(r"(config|docs|tests|scripts|bags)/", a) and not (ROOT / a).exists()]
    assert not bad, bad


def test_own_satellite_walkthrough_goes_from_the_tle_and_hardware_file_to_export():
    """The walk-through of the 12U starts from the TLE spacecraft file and the hardware file and runs
    fit-field -> tune -> verify -> sil --environment full -> export -> export-check on the export's own
    vectors, every command given both files (fit-field: the spacecraft file), each /tmp input written by
    an earlier command's --out, and the files it starts from hold a TLE file and a hardware file."""
    from magtune_core.base.paramfile import read_ros_params

    steps = _magtune_lines(_section(OWN_SATELLITE.read_text(), WALKTHROUGH))
    args = [_parse(argv[1:]) for argv in steps]
    assert [a.command for a in args] == ["fit-field", "tune", "verify", "sil", "export", "export-check"], steps
    example = "config/examples/cubesat12u/"
    tle, hardware = example + "spacecraft_tle.yaml", example + "hardware.yaml"
    assert read_ros_params(ROOT / tle, "simulator").get("tle_file") == "cubesat12u.tle"
    assert (ROOT / example / "cubesat12u.tle").is_file() and (ROOT / hardware).is_file()
    spacecraft = {"fit-field": "spacecraft", "tune": "config", "verify": "config", "sil": "spacecraft", "export": "spacecraft"}
    written = []
    for argv, a in zip(steps, args):
        if a.command in spacecraft:
            assert getattr(a, spacecraft[a.command]) == tle, argv
        if a.command not in ("fit-field", "export-check"):
            assert a.hardware == hardware, argv
        if a.command == "sil":
            assert a.environment == "full", argv
        inputs = [x for x in argv if x.startswith("/tmp/") and x != getattr(a, "out", None)]
        orphans = [x for x in inputs if not any(x == w or x.startswith(w.rstrip("/") + "/") for w in written)]
        assert not orphans, f"{argv}: {orphans} not written by an earlier command"
        if getattr(a, "out", None):
            written.append(a.out)
    assert args[-1].vectors == args[-1].outputs == f"{args[-2].out}/flight_vectors.csv", steps[-1]
