"""Self-contained HTML reports, checked in a real browser; the paper reproduction."""

import io
import json
import re
from pathlib import Path

import numpy as np
import pytest

from furuta_cosim.reproduce import reproduce

from helpers import run_cli

CHROMIUM, DRIVER = Path("/usr/bin/chromium"), Path("/usr/bin/chromedriver")


@pytest.fixture(scope="module")
def reproduction(tmp_path_factory):
    folder = tmp_path_factory.mktemp("reproduction")
    document = reproduce(folder, budget="quick", workers=2)
    return folder, document


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """A simulate, a regress and a tune run directory, each with its report."""
    folder = tmp_path_factory.mktemp("runs")
    from furuta_cosim.cli import main

    assert main(["simulate", "paper-step", "-o", str(folder / "simulate"), "--every", "10"]) == 0
    assert main(["regress", "paper-step", "toy-step", "-o", str(folder / "regress"), "--workers", "1"]) == 0
    assert main(["tune", "paper-spectral", "-o", str(folder / "tune"), "--n-calls", "12", "--workers", "1"]) == 0
    for kind in ("simulate", "regress", "tune"):
        assert main(["report", str(folder / kind)]) == 0
    return folder


def test_every_printed_number_and_claim_has_a_value_and_a_verdict(reproduction):
    folder, document = reproduction
    claims = document["claims"]
    topics = " ".join(c["topic"] for c in claims)
    for expected in ("A, linearized", "A(2,2)", "B, linearized", "K, LQR", "published BO controller stable on the printed",
                     "calibrated plant", "toy: eig(Abar)", "toy: eig(A - BK)", "toy: prefilters",
                     "less effort", "LQR brings the pendulum back", "BO (30 calls)",
                     "block formula", "Table taken literally", "Table friction 1e-4",
                     "sine reference (10 s period)", "re-weighting the LQR"):
        assert expected in topics, expected
    for claim in claims:
        assert claim["ours"] and claim["verdict"] in ("holds", "holds under a reading", "does not hold"), claim
        assert claim["rule"], claim  # every verdict says the rule it follows from
        # the verdict is the rule's outcome, read under a named reading or not
        assert claim["verdict"] == ("does not hold" if not claim["passed"] else
                                    "holds under a reading" if claim["reading"] else "holds")
    verdicts = {c["topic"]: c["verdict"] for c in claims}
    assert verdicts["A(2,2)"] == "does not hold"
    assert verdicts["toy: eig(Abar) by the paper's block formula"] == "does not hold"
    assert verdicts["the LQR follows the sine reference (10 s period)"] == "does not hold"
    assert verdicts["the LQR follows the sine-follow reference (60 s period)"] == "holds"
    # the paper column holds only what the paper prints: no value of ours for the prefilters
    prefilters = next(c for c in claims if c["topic"].startswith("toy: prefilters"))
    assert "2.0" not in prefilters["paper"] and "1.3667" not in prefilters["paper"]
    assert verdicts["K, LQR with Q = diag(1, 10, 100, 10, 1), R = 10"] == "holds under a reading"
    md = (folder / "reproduction.md").read_text()
    assert md.count("\n| ") == len(claims) + 1          # header + one row per claim
    assert "paper-readings.md" in md
    assert {p.name for p in (folder / "figures").glob("*.svg")} >= {"paper-step.svg", "toy-step.svg",
                                                                    "toy-sine.svg", "convergence-paper-spectral.svg",
                                                                    "fronts-seed0.svg"}


def test_the_html_is_self_contained(reproduction, runs):
    pages = [reproduction[0] / "reproduction.html"] + [runs / k / "report.html" for k in ("simulate", "regress", "tune")]
    for path in pages:
        text = path.read_text()
        assert "<script" not in text.lower()
        # nothing fetched: no external stylesheet, image or frame
        assert not re.search(r'(src|href)="(https?:)?//', text), path
        assert not re.search(r'<link[^>]+stylesheet', text), path
    assert "<svg" in (runs / "simulate" / "report.html").read_text()


def test_the_reports_say_what_they_are_about(runs):
    simulate = (runs / "simulate" / "report.html").read_text()
    assert "Scenario paper-step" in simulate and "FMU sha256" in simulate and "PASS" in simulate
    regress = (runs / "regress" / "report.html").read_text()
    assert "everything matches its baseline" in regress and "toy-classical" in regress
    tune = (runs / "tune" / "report.html").read_text()
    assert "Tuning paper-spectral" in tune and "seed" in tune and "Spec" in tune


def test_report_of_a_folder_that_is_no_run_is_one_line(tmp_path, capsys):
    code, _, err = run_cli(capsys, "report", str(tmp_path))
    assert code == 2 and "not a run directory" in err and len(err.strip().splitlines()) == 1


def _browser():
    if not (CHROMIUM.is_file() and DRIVER.is_file()):
        pytest.skip("no browser: Debian's chromium and chromium-driver are not installed "
                    "(.ci/run installs them)")
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = str(CHROMIUM)
    for flag in ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                 "--disable-background-networking", "--disable-component-update", "--disable-sync",
                 "--window-size=1280,1600"):
        options.add_argument(flag)
    options.set_capability("goog:loggingPrefs", {"browser": "ALL"})
    return webdriver.Chrome(options=options, service=Service(str(DRIVER)))


@pytest.mark.parametrize("which", ["reproduction", "simulate", "tune"])
def test_a_real_browser_opens_the_report(reproduction, runs, tmp_path, which):
    import matplotlib.image

    path = (reproduction[0] / "reproduction.html" if which == "reproduction"
            else runs / which / "report.html")
    driver = _browser()
    try:
        driver.get(path.resolve().as_uri())
        assert driver.title.startswith("furuta-cosim")
        errors = [e for e in driver.get_log("browser") if e["level"] in ("SEVERE", "WARNING")]
        assert errors == []
        images = driver.execute_script(
            "return Array.from(document.images).map(i => [i.complete, i.naturalWidth])")
        assert all(done and width > 0 for done, width in images), images
        figures = driver.execute_script(
            "return Array.from(document.querySelectorAll('figure svg')).map(s => s.getBBox().width)")
        assert figures and min(figures) > 100
        shot = matplotlib.image.imread(io.BytesIO(driver.get_screenshot_as_png()), format="png")
    finally:
        driver.quit()
    # not blank: many distinct shades, dark text on the light page
    assert shot.shape[0] > 500 and float(np.std(shot)) > 0.02
    assert float(np.min(shot[..., :3])) < 0.3


def test_figures_and_tables_take_names_and_units_from_the_plant(tmp_path, capsys):
    """No pendulum names in generic code: the rows and axes of a run come from the FMU's
    declared units (the outputs in the tracked output's unit are watched) and the metric
    catalogue's table, for this plant and for a plant that declares no units."""
    import json

    from furuta_cosim.cli import main
    from furuta_cosim.cosim.result import RunResult
    from furuta_cosim.metrics import table_keys
    from furuta_cosim.report.figures import default_signals

    assert main(["simulate", "paper-step", "-o", str(tmp_path / "step"), "--every", "10"]) == 0
    printed = capsys.readouterr().out
    document = json.loads((tmp_path / "step" / "metrics.json").read_text())
    trace = RunResult.from_dict(document["controllers"]["lqr-paper"], base=tmp_path / "step").trace
    assert trace.units["theta0"] == "rad" and trace.units["V"] == "V"
    assert trace.watched() == ["theta1"]  # the only other output in rad
    assert default_signals(trace) == ["theta0", "theta1", "u"]
    assert trace.label("theta1") == "theta1 [rad]" and trace.label("u") == "V [V]"
    assert trace.label("dtheta1") == "dtheta1 [rad/s]"
    assert table_keys("theta0", ["theta1"])[-2:] == ["theta1.max_abs", "theta1.SettlingTime"]
    assert "theta1.max_abs" in printed and "dtheta1.max_abs" not in printed

    trace.units = {}  # a plant that declares no units: its tracked output and its input only
    assert trace.watched() == [] and default_signals(trace) == ["theta0", "u"]
    assert trace.label("theta1") == "theta1"


def test_each_verdict_rule_on_numbers_by_hand():
    from furuta_cosim.reproduce import at_most, below, rounds_to, same_set, truncates_to, within

    assert rounds_to([2.994], [2.99]) and not rounds_to([2.996], [2.99])
    assert rounds_to([-0.0311], [-0.03]) and not rounds_to([-0.0311], [-0.31])
    assert rounds_to([100.4], [100.0]) and not rounds_to([100.6], [100.0])
    assert truncates_to([-0.310523, 70.7488], [-0.31, 70.74])
    assert not truncates_to([-0.3223], [-0.31]) and not truncates_to([70.7499], [70.75])
    assert same_set([0.8, -0.5, 0.59 + 0.001j], [0.5, 0.59, 0.8], 5e-3)
    assert not same_set([0.5, 0.99, 0.4768], [0.5, 0.59, 0.8], 5e-3)
    assert not same_set([0.5, 0.8], [0.5, 0.59, 0.8], 5e-3)   # a missing value fails
    assert within([1.0 + 1e-10], [1.0], 1e-9) and not within([1.0 + 1e-8], [1.0], 1e-9)
    assert below(0.99, 1.0) and not below(1.0, 1.0) and not below(float("nan"), 1.0)
    assert at_most(1.0, 1.0) and not at_most(float("inf"), 1.0)


def test_a_run_folder_moved_elsewhere_is_whole(tmp_path, capsys):
    """metrics.json named each trace by the absolute path it was written to: a run folder moved
    or shared pointed back to the machine it came from."""
    import shutil

    code, out, err = run_cli(capsys, "simulate", "paper-step", "-o", str(tmp_path / "here"))
    assert code in (0, 1), err
    text = (tmp_path / "here" / "metrics.json").read_text()
    assert str(tmp_path) not in text
    shutil.move(tmp_path / "here", tmp_path / "moved")
    code, out, err = run_cli(capsys, "report", str(tmp_path / "moved"))
    assert code == 0, err
    page = (tmp_path / "moved" / "report.html").read_text()
    assert str(tmp_path / "here") not in page and "<svg" in page
    document = json.loads((tmp_path / "moved" / "metrics.json").read_text())
    from furuta_cosim.cosim.result import RunResult

    trace = RunResult.from_dict(document["controllers"]["lqr-paper"], base=tmp_path / "moved").trace
    assert len(trace.t) > 100


def _paths_in(folder, tmp_path):
    """Every text file of ``folder`` that names a path under ``tmp_path`` (the machine's)."""
    found = []
    for path in folder.rglob("*"):
        if path.is_file() and path.suffix in (".json", ".md", ".yaml", ".html", ".csv", ".txt"):
            if str(tmp_path) in path.read_text(errors="replace"):
                found.append(path.name)
    return found


@pytest.mark.slow
def test_rig_replay_and_tuning_folders_name_no_path_of_the_machine(tmp_path, capsys):
    """A rig run's summary named its plant file by absolute path and replay.json its experiment:
    a folder moved or shared pointed back to the machine it came from. Every report names its
    files relative to its folder (and the plant by name and content hash); a moved rig folder's
    log replays as it did."""
    import shutil

    rig = tmp_path / "rig"
    code, out, err = run_cli(capsys, "rig", "run", "swingup-qube", "--board", "virtual:fast",
                             "--duration", "2", "-o", str(rig))
    assert code == 0, err
    summary = json.loads((rig / "summary.json").read_text())
    assert summary["plant"] == "qube-servo-3.yaml" and len(summary["plant_sha256"]) == 64
    code, out, err = run_cli(capsys, "replay", str(rig / "experiment.yaml"), "--plant", "qube-servo-3",
                             "-o", str(tmp_path / "replay"))
    assert code in (0, 1), err  # 1: its current's replay is beyond 20 noise floors (a swing-up)
    first = json.loads((tmp_path / "replay" / "replay.json").read_text())
    code, out, err = run_cli(capsys, "tune", "paper-spectral", "--n-calls", "3", "-o", str(tmp_path / "tune"))
    assert code == 0, err
    for folder in ("rig", "replay", "tune"):
        assert _paths_in(tmp_path / folder, tmp_path) == [], folder
    shutil.move(rig, tmp_path / "moved")
    code, out, err = run_cli(capsys, "replay", str(tmp_path / "moved" / "experiment.yaml"),
                             "--plant", "qube-servo-3", "-o", str(tmp_path / "again"))
    assert code in (0, 1), err
    again = json.loads((tmp_path / "again" / "replay.json").read_text())
    assert again["experiments"] == first["experiments"]
    assert first["experiments"]["rig"]["outputs"]["theta1"]["floors"] < 1.0
