"""``hfdi-validate figures``, ``stability`` and ``all`` on cheap cases."""
import json
import re
import struct
import subprocess
import sys

import numpy as np
import pytest

from hfdi.spectral import spectral_properties
from validation.cli import main

# every test here runs the figure and report commands end to end: not in the quick loop
pytestmark = pytest.mark.slow

PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
DUMBBELL_FIGURES = {
    "dumbbell_fig04_configurations.png", "dumbbell_fig05_stretch.png",
    "dumbbell_fig06_energy_increment.png", "dumbbell_fig07_energy_ratio_long.png",
    "dumbbell_fig09_eps_u.png", "dumbbell_fig10_eps_stretch.png",
    "dumbbell_fig11_step_size.png",
}
STABILITY_FIGURES = {"stability_fig01_spectral_radius.png",
                     "stability_fig02_period_elongation_amplitude_decay.png"}
# A short dumbbell: its IDA reference takes about a second.
CHEAP = ["--t-end", "0.2", "--targets", "3.0,4.0"]


@pytest.fixture(scope="module")
def cache_dir(tmp_path_factory):
    """One reference cache for the whole module, so each reference is computed once."""
    return tmp_path_factory.mktemp("cache")


@pytest.fixture(autouse=True)
def _private_cache(monkeypatch, cache_dir):
    monkeypatch.setenv("HFDI_CACHE_DIR", str(cache_dir))


def assert_png(path):
    data = path.read_bytes()
    assert data[:8] == PNG_SIGNATURE, path
    assert data[12:16] == b"IHDR"
    width, height = struct.unpack(">II", data[16:24])
    assert width >= 400 and height >= 300, (path, width, height)
    assert len(data) > 10_000, path   # a drawn figure, not an empty canvas


def test_figures_writes_the_named_pngs(tmp_path, capsys):
    out = tmp_path / "figs"
    assert main(["figures", "dumbbell", "--out", str(out), *CHEAP]) == 0
    assert {p.name for p in out.iterdir()} == DUMBBELL_FIGURES   # no temporary files left
    for path in out.iterdir():
        assert_png(path)
    captured = capsys.readouterr()
    assert set(captured.out.split()) == {str(out / name) for name in DUMBBELL_FIGURES}
    progress = captured.err.splitlines()
    assert all(re.match(r"\[\s*\d+\.\d s\] ", line) for line in progress)
    assert any("reference dumbbell" in line for line in progress)
    assert sum(" run dumbbell " in line for line in progress) >= 6
    assert sum(" figure " in line for line in progress) == len(DUMBBELL_FIGURES)


_TITLES = {"Newmark": "newmark", "Bathe": "bathe", "HFDI": "hfdi",
           "GeneralizedAlpha": "generalized_alpha"}


def _parse_table(text):
    rows = {}
    for line in text.splitlines():
        cells = line.split()
        if len(cells) == 5 and cells[0] in _TITLES:
            rows[_TITLES[cells[0]], float(cells[1])] = [
                np.nan if c == "-" else float(c) for c in cells[2:]]
    return rows


def test_stability_writes_both_figures_and_prints_the_spectral_values(tmp_path, capsys):
    out = tmp_path / "stab"
    ratios = [0.01, 0.1, 0.3, 1.0, 10.0]
    assert main(["stability", "--out", str(out), "--ratios", ",".join(map(str, ratios))]) == 0
    assert {p.name for p in out.iterdir()} == STABILITY_FIGURES
    for path in out.iterdir():
        assert_png(path)
    rows = _parse_table(capsys.readouterr().out)
    assert len(rows) == 3 * len(ratios)
    for scheme in ("newmark", "bathe", "hfdi"):
        props = spectral_properties(scheme, ratios)
        for k, ratio in enumerate(ratios):
            rho, pe, ad = rows[scheme, ratio]
            assert rho == pytest.approx(props.spectral_radius[k], abs=1e-6)
            assert pe == pytest.approx(props.period_elongation[k], abs=1e-4)
            assert ad == pytest.approx(props.amplitude_decay[k], abs=1e-4)
    # the paper's claims: HFDI damps high frequencies, Newmark conserves
    assert rows["hfdi", 10.0][0] < 0.05 and rows["newmark", 10.0][0] == pytest.approx(1.0)


def test_stability_of_generalized_alpha_beside_hfdi(tmp_path, capsys):
    """``stability --schemes``: any scheme of hfdi.SCHEMES, its curves drawn and
    its ρ, PE and AD in the table; generalized-α keeps ρ∞ = 0.8 at large Δt/T."""
    out = tmp_path / "stab"
    ratios = [0.01, 0.1, 1e5]
    assert main(["stability", "--out", str(out), "--schemes", "generalized_alpha,hfdi",
                 "--ratios", ",".join(map(str, ratios))]) == 0
    assert {p.name for p in out.iterdir()} == STABILITY_FIGURES
    for path in out.iterdir():
        assert_png(path)
    rows = _parse_table(capsys.readouterr().out)
    assert {scheme for scheme, _ in rows} == {"generalized_alpha", "hfdi"}
    props = spectral_properties("generalized_alpha", ratios)
    for k, ratio in enumerate(ratios):
        assert rows["generalized_alpha", ratio][0] == pytest.approx(
            props.spectral_radius[k], abs=1e-6)
    assert rows["generalized_alpha", 1e5][0] == pytest.approx(0.8, abs=1e-3)


def test_figures_of_generalized_alpha_runs(tmp_path, capsys):
    """``figures --schemes generalized_alpha``: its table runs in the error
    figures (its own targets); the figures of the paper's named runs as ever."""
    out = tmp_path / "figs"
    assert main(["figures", "dumbbell", "--out", str(out), "--schemes", "generalized_alpha",
                 "--t-end", "0.2"]) == 0
    assert {p.name for p in out.iterdir()} == DUMBBELL_FIGURES
    for path in out.iterdir():
        assert_png(path)
    runs = [line for line in capsys.readouterr().err.splitlines() if " run dumbbell " in line]
    assert sum("GeneralizedAlpha N̄ = " in line for line in runs) == 5


def test_all_writes_the_report_and_resumes(tmp_path, capsys):
    out = tmp_path / "all"
    args = ["all", "--out", str(out), "--problems", "dumbbell", *CHEAP]
    assert main(args) == 0
    first = capsys.readouterr()
    report = (out / "report.md").read_text()

    records = json.loads((out / "dumbbell_table.json").read_text())
    assert [(r["scheme"], r["target"]) for r in records] == [
        (s, t) for s in ("newmark", "bathe", "hfdi") for t in (3.0, 4.0)]
    assert all(set(r["eps"]) == {"u", "stretch"} for r in records)
    # the table beside the paper's numbers, and the ε rows
    assert "## Dumbbell (paper Table 2)" in report
    assert "| steps (paper) |" in report and "| Bathe | 2·4.0 | " in report
    assert "| 73 |" in report                      # the paper's steps of Bathe 2·4.0
    eps_u = records[-2]["eps"]["u"]                # HFDI 3.0
    assert f"{eps_u:.2e}" in report
    # every figure linked relatively, and every link resolves to a PNG
    links = re.findall(r"\]\((figures/[^)]+\.png)\)", report)
    assert {link.split("/")[1] for link in links} == DUMBBELL_FIGURES | STABILITY_FIGURES
    for link in links:
        assert_png(out / link)
    # the reference-convergence section, with a tighter reference that moves ε by < 1 %
    conv = json.loads((out / "dumbbell_reference_convergence.json").read_text())
    assert conv["tight_rtol"] == 1e-13 and len(conv["runs"]) == len(records)
    assert 0 <= conv["max_relative_change"] < 0.01
    assert "## Reference convergence" in report and "below 1 %" in report
    assert "## Stability and accuracy" in report and "| HFDI | 10 |" in report
    assert "reference dumbbell" in first.err and "rtol 1e-13" in first.err

    # a second call skips every output already written
    outputs = sorted(p for p in out.rglob("*")
                     if p.is_file() and p.name != "hfdi-validate-all.json")
    stamps = {p: p.stat().st_mtime_ns for p in outputs}
    assert main(args) == 0
    second = capsys.readouterr().err
    assert {p: p.stat().st_mtime_ns for p in outputs} == stamps
    assert second.count("exists, skipped") == len(outputs)
    assert " run " not in second and "rtol 1e-12" not in second

    # an output lost (say, interrupted before it was written) is redone on resume,
    # with the report that links it; the rest stays as it was
    lost = out / "figures" / "dumbbell_fig11_step_size.png"
    lost.unlink()
    assert main(args) == 0
    capsys.readouterr()
    assert_png(lost)
    changed = {p for p in outputs if p.stat().st_mtime_ns != stamps[p]}
    assert changed == {lost, out / "report.md"}

    # outputs of the Python path are not resumed by compiled runs (t_T differs)
    assert main(args + ["--compiled"]) == 2
    assert "compiled: None there, True now" in capsys.readouterr().err

    # other settings in the same directory: refused in one line
    assert main(["all", "--out", str(out), "--problems", "dumbbell", "--t-end", "0.3"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "other settings" in err[0] and "--force" in err[0]


@pytest.mark.parametrize("args", [
    ["figures", "pendulum", "--out", "{tmp}/x"],
    ["figures", "dumbbell", "--out", "{file}"],
    ["figures", "dumbbell"],
    ["figures", "dumbbell", "--out", "{tmp}/x", "--t-end", "0"],
    ["stability", "--out", "{tmp}/x", "--ratios", "0.1,-1"],
    ["stability", "--out", "{tmp}/x", "--ratios", "a"],
    ["all", "--out", "{tmp}/x", "--problems", "dumbbell,pendulum"],
    ["all", "--out", "{tmp}/x", "--targets", "0.5"],
])
def test_bad_input_exits_2_with_one_line(args, tmp_path, capsys):
    (tmp_path / "file").write_text("")
    args = [a.format(tmp=tmp_path, file=tmp_path / "file") for a in args]
    try:
        code = main(args)
    except SystemExit as exc:       # argparse's own checks
        code = exc.code
    assert code == 2
    captured = capsys.readouterr()
    err = captured.err.strip().splitlines()
    assert len(err) == 1 and "error" in err[0], err
    assert not (tmp_path / "x").exists() or not any((tmp_path / "x").iterdir())


def test_bad_input_has_no_traceback_from_the_command_line(tmp_path):
    proc = subprocess.run([sys.executable, "-m", "validation", "figures", "pendulum", "--out",
                           str(tmp_path)], capture_output=True, text=True)
    assert proc.returncode == 2
    assert proc.stderr.count("\n") == 1 and "Traceback" not in proc.stderr
    assert "unknown problem 'pendulum'" in proc.stderr
