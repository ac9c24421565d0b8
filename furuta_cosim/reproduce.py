"""``furuta-cosim reproduce``: the paper, claim by claim, with our value and a verdict.

Each printed number and claim of Solis & Thomas (2021) becomes a row: what the paper says,
what the project computes, and a verdict: ``holds``, ``holds under a reading`` (a reading of
docs/pages/paper-readings.md, named in the row), or ``does not hold``. The runs behind the rows
(scenarios, a tuning) are kept under the output folder, with the figures the paper's PDF
left empty. Written as ``reproduction.md`` and ``reproduction.html`` (self-contained).
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np

from furuta_cosim.defaults import PAPER_PERIOD
from furuta_cosim.design.lqr import PAPER_Q, PAPER_R
from furuta_cosim.documents import dumps
from furuta_cosim.files import copy, output_folder, write_text

BUDGETS = {"quick": 30, "full": 150}
READINGS = "docs/pages/paper-readings.md"
PRINTED_K = [-0.31, -5.26, 70.74, 8.92, 0.17]


@dataclass
class Claim:
    """One row: what the paper prints (only that), what we compute, the rule that turns the
    numbers into the verdict, and whether they pass it."""

    topic: str
    paper: str              # what the paper prints, or "not printed" with what it says
    ours: str
    rule: str               # the stated rule, applied to the numbers in ``ours``
    passed: bool
    reading: str = ""       # the reading of docs/pages/paper-readings.md the rule is checked under
    note: str = ""

    @property
    def verdict(self) -> str:
        if not self.passed:
            return "does not hold"
        return "holds under a reading" if self.reading else "holds"

    def row(self) -> list[str]:
        note = "; ".join(t for t in (self.reading, self.note) if t)
        return [self.topic, self.paper, self.ours, self.rule, self.verdict, note]

    def as_dict(self) -> dict:
        return {**self.__dict__, "verdict": self.verdict}


# -- the rules: each verdict follows from the numbers of its row by one of these --------------
def rounds_to(values, printed) -> bool:
    """Every value, rounded to as many decimals as its printed number shows, is that number."""
    return all(round(float(v), _decimals(p)) == float(p) for v, p in zip(np.ravel(values), np.ravel(printed)))


def truncates_to(values, printed) -> bool:
    """Every value, truncated to as many decimals as its printed number shows, is that number."""
    return _truncate(np.ravel(values), np.ravel(printed)) == [float(p) for p in np.ravel(printed)]


def same_set(values, printed, tolerance: float) -> bool:
    """The two sets of numbers (magnitudes, sorted) agree entry by entry within ``tolerance``."""
    a, b = np.sort(np.abs(np.ravel(values))), np.sort(np.abs(np.ravel(printed)))
    return a.shape == b.shape and bool(np.all(np.abs(a - b) <= tolerance))


def within(value, reference, relative: float) -> bool:
    """|value - reference| <= relative |reference|, for every entry."""
    value, reference = np.ravel(value), np.ravel(reference)
    return bool(np.all(np.abs(value - reference) <= relative * np.abs(reference)))


def below(value, reference) -> bool:
    """value < reference (both finite)."""
    return bool(np.isfinite(value) and np.isfinite(reference) and value < reference)


def at_most(value, reference) -> bool:
    """value <= reference (both finite)."""
    return bool(np.isfinite(value) and np.isfinite(reference) and value <= reference)


def _vector(values, digits=4) -> str:
    return "[" + " ".join(f"{v:.{digits}g}" for v in values) + "]"


def _decimals(printed: float) -> int:
    text = repr(float(printed))
    return 0 if text.endswith(".0") or "e" in text else len(text.split(".")[1])


def _truncate(values, like):
    """``values`` truncated to as many decimals as each printed number has."""
    out = []
    for v, p in zip(values, like):
        scale = 10 ** _decimals(p)
        out.append(float(np.trunc(v * scale) / scale))
    return out


# -- the rows ------------------------------------------------------------------------------------
def model_claims() -> list[Claim]:
    from furuta_cosim.models import load_model

    printed, derived = load_model("paper-printed"), load_model("derived")
    literal = load_model("derived:table-literal")
    A, Ad = printed.A, derived.A
    mask = np.ones_like(A, bool)
    mask[1, 1] = False
    matching = sum(rounds_to([d], [a]) for d, a in zip(Ad[mask], A[mask]))
    literal_matching = sum(rounds_to([d], [a]) for d, a in zip(literal.A.ravel(), A.ravel()))
    relB = float(np.max(np.abs(derived.B - printed.B) / np.where(np.abs(printed.B) > 0, np.abs(printed.B), 1.0)))
    return [
        Claim("A, linearized plant (Sec. V-B)", "printed 5x5 A",
              f"{matching} of the {int(mask.sum())} entries other than A(2,2) round to the printed digits",
              "every entry rounds to its printed digits", matching == mask.sum(),
              f"one effective gear ratio, friction 1e-3, back-EMF form ({READINGS} §1)"),
        Claim("A(2,2)", f"{A[1, 1]:g}", f"{Ad[1, 1]:.4g}", "rounds to the printed digits",
              rounds_to([Ad[1, 1]], [A[1, 1]]),
              note=f"no friction value gives the printed entry ({READINGS} §1)"),
        Claim("A from the parameter Table taken literally", "printed 5x5 A",
              f"{literal_matching} of the 25 entries round to the printed digits "
              f"(A(5,2) = {literal.A[4, 1]:.4g} against {A[4, 1]:g})",
              "every entry rounds to its printed digits", literal_matching == A.size,
              note=f"the Table's gear ratio Kg = 59927 is not the one behind the printed A ({READINGS} §1)"),
        Claim("B, linearized plant", _vector(printed.B.ravel()), _vector(derived.B.ravel()),
              "every entry within 1 %", relB < 0.01, note=f"largest difference {relB:.2%}"),
    ]


def lqr_claims() -> list[Claim]:
    from furuta_cosim.design import lqr
    from furuta_cosim.models import load_model

    model = load_model("paper-printed")
    discrete = lqr(model, np.diag(PAPER_Q), np.diag([PAPER_R]), PAPER_PERIOD).Dc[0]
    continuous = lqr(model, np.diag(PAPER_Q), np.diag([PAPER_R]), None).Dc[0]
    worst = float(np.max(np.abs(continuous - PRINTED_K) / np.abs(PRINTED_K)))
    return [
        Claim("K, LQR with Q = diag(1, 10, 100, 10, 1), R = 10", _vector(PRINTED_K),
              _vector(discrete, 6) + " (discrete LQR at 2 ms)", "truncates to the printed digits",
              truncates_to(discrete, PRINTED_K), f"the printed K is a discrete LQR at 2 ms ({READINGS} §2)"),
        Claim("K as a continuous LQR", _vector(PRINTED_K), _vector(continuous, 5),
              "truncates to the printed digits", truncates_to(continuous, PRINTED_K),
              note=f"up to {worst:.1%} away"),
    ]


def published_controller_claims() -> list[Claim]:
    from furuta_cosim.controllers import check_fits, load_controller
    from furuta_cosim.design import analyze
    from furuta_cosim.models import load_model

    cfile = load_controller("bo-paper")
    rows = []
    for model_name, label in (("paper-printed", "printed model"), ("derived", "calibrated plant (linearized)")):
        model = load_model(model_name)
        analysis = analyze(model, check_fits(cfile, model).controller)
        dominant = analysis.dominant
        rows.append(Claim(f"published BO controller stable on the {label}",
                          "stable (the paper's controller)",
                          f"slowest mode {dominant.eigenvalue.real:.4g} ± {abs(dominant.eigenvalue.imag):.4g}j",
                          "every eigenvalue of Abar has a negative real part", analysis.stable,
                          note=(f"Bc = 0: the controller state never sees the plant ({READINGS} §3)"
                                if model_name == "paper-printed" else
                                f"stability turns on the pendulum friction alone ({READINGS} §3)")))
    return rows


def toy_claims(runs: dict) -> list[Claim]:
    from furuta_cosim.controllers import check_fits, load_controller
    from furuta_cosim.design import analyze
    from furuta_cosim.design.controller import augmented
    from furuta_cosim.design.prefilter import dc_gain
    from furuta_cosim.models import load_model

    model = load_model("toy")
    rows = []
    gen = check_fits(load_controller("toy-generalized"), model)
    cls = check_fits(load_controller("toy-classical"), model)
    eig = np.linalg.eigvals(augmented(model, gen.controller)[0])
    eig_classical = analyze(model, cls.controller).eigenvalues
    rows.append(Claim("toy: eig(Abar) of the generalized controller", "{0.5, 0.59, 0.8}",
                      "{" + ", ".join(f"{v:.4g}" for v in np.sort(np.abs(eig))) + "}",
                      "the same magnitudes within 5e-3", same_set(eig, [0.5, 0.59, 0.8], 5e-3),
                      note=f"computed directly from Abar ({READINGS} §4)"))
    # the paper's block formula: eig(A - B Dc) with the dominant eig(Ac + Bc (A - B Dc)^-1 B Cc)
    c = gen.controller
    closed = model.A - model.B @ c.Dc
    block = np.concatenate([np.linalg.eigvals(closed),
                            np.linalg.eigvals(c.Ac + c.Bc @ np.linalg.solve(closed, model.B @ c.Cc))])
    rows.append(Claim("toy: eig(Abar) by the paper's block formula", "{0.5, 0.59, 0.8} (Sec. IV)",
                      "{" + ", ".join(f"{v:.4g}" for v in np.sort(np.abs(block))) + "}",
                      "the same magnitudes as eig(Abar) within 5e-3", same_set(block, eig, 5e-3),
                      note=f"the formula is not right in general ({READINGS} §4)"))
    rows.append(Claim("toy: eig(A - BK) of the classical controller", "{0.5, 0.8}",
                      "{" + ", ".join(f"{v:.4g}" for v in np.sort(np.abs(eig_classical))) + "}",
                      "the same magnitudes within 5e-3", same_set(eig_classical, [0.5, 0.8], 5e-3)))
    gains = [dc_gain(model, x.controller, x.tracked_output) * x.F for x in (cls, gen)]
    rows.append(Claim("toy: prefilters F give unit DC gain", "formula only (Sec. IV), no values printed",
                      f"F = {cls.F:.5g} (classical), {gen.F:.5g} (generalized); DC gain with F "
                      f"{gains[0]:.12g}, {gains[1]:.12g}", "DC gain from r to y with F within 1e-9 of 1",
                      within(gains, [1.0, 1.0], 1e-9),
                      note=f"the paper's (A - I) form is the discrete-time formula ({READINGS} §4)"))
    step, sine = runs["toy-step"]["controllers"], runs["toy-sine"]["controllers"]
    peaks = {kind: {n: runs[f"toy-{kind}"]["controllers"][n]["metrics"]["u.peak_abs"]
                    for n in ("toy-classical", "toy-generalized")} for kind in ("step", "sine")}
    rms = {n: sine[n]["metrics"].get("error.RMS") for n in ("toy-classical", "toy-generalized")}
    rows.append(Claim("toy: the generalized controller tracks as well with less effort", "claimed (figures)",
                      f"peak |u| step {peaks['step']['toy-classical']:.4g} vs {peaks['step']['toy-generalized']:.4g}, "
                      f"sine {peaks['sine']['toy-classical']:.4g} vs {peaks['sine']['toy-generalized']:.4g}; "
                      f"sine RMS error {rms['toy-classical']:.4g} vs {rms['toy-generalized']:.4g} "
                      "(classical vs generalized)",
                      "lower peak |u| on both runs and an RMS error on the sine no higher",
                      below(peaks["step"]["toy-generalized"], peaks["step"]["toy-classical"])
                      and below(peaks["sine"]["toy-generalized"], peaks["sine"]["toy-classical"])
                      and at_most(rms["toy-generalized"], rms["toy-classical"]),
                      note=f"the step's peak is the plant's steady state ({READINGS} §4)"))
    del step
    return rows


def pendulum_claims(runs: dict, friction: dict) -> list[Claim]:
    """``friction``: paper-step's metrics of both controllers on the plant with the Table's
    friction 1e-4, over a run long enough for the published controller to settle."""
    step = runs["paper-step"]["controllers"]
    lqr, bo = step["lqr-paper"]["metrics"], step["bo-paper"]["metrics"]
    settled = lqr.get("theta1.SettlingTime")
    low_lqr, low_bo = friction["lqr-paper"], friction["bo-paper"]
    return [
        Claim("LQR brings the pendulum back from 0.1 rad (nonlinear plant)", "figure (empty in the PDF)",
              f"settles in {settled:.3g} s, peak |u| {lqr['u.peak_abs']:.3g} V",
              "theta1 settles (2 %) within 1.5 s", at_most(settled, 1.5)),
        Claim("published BO controller on the nonlinear calibrated plant", "figure (empty in the PDF)",
              f"theta1 reaches {bo['theta1.max_abs']:.3g} rad, RMS voltage {bo['u.rms']:.3g} V",
              "|theta1| stays within its 0.1 rad release", at_most(bo["theta1.max_abs"], 0.1 + 1e-9),
              note=f"unstable with friction 1e-3 ({READINGS} §5)"),
        Claim("published BO controller, where it is stable (Table friction 1e-4): less voltage than the LQR",
              "figure (empty in the PDF)",
              f"peak |u| {low_bo['u.peak_abs']:.4g} V against {low_lqr['u.peak_abs']:.4g} V, RMS "
              f"{low_bo['u.rms']:.3g} V against {low_lqr['u.rms']:.3g} V; theta1 settles in "
              f"{low_bo['theta1.SettlingTime']:.4g} s against {low_lqr['theta1.SettlingTime']:.3g} s",
              "lower peak and RMS voltage than the LQR",
              below(low_bo["u.peak_abs"], low_lqr["u.peak_abs"]) and below(low_bo["u.rms"], low_lqr["u.rms"]),
              note=f"paper-step over {FRICTION_RUN:g} s ({READINGS} §5)"),
    ]


# the published controller settles in about 104 s with the Table's friction: the run is longer
FRICTION_RUN = 200.0
PUBLISHED_OBJECTIVE_TEXT = "Ac = -100, Bc = 0, Cc = -0.5, Dc printed (objective value not printed)"


def friction_runs() -> dict:
    """paper-step on the plant with the Table's friction (C0 = C1 = 1e-4), FRICTION_RUN long."""
    import tempfile

    import yaml

    from furuta_cosim import paths
    from furuta_cosim.cosim import evaluate, prepare
    from furuta_cosim.cosim.worker import session_for
    from furuta_cosim.scenario import load_scenario

    data = yaml.safe_load((paths.scenarios() / "paper-step.yaml").read_text())
    data["timing"]["duration"] = FRICTION_RUN
    with tempfile.TemporaryDirectory() as folder:
        path = Path(folder) / "paper-step-long.yaml"
        path.write_text(yaml.safe_dump(data))
        prepared = prepare(load_scenario(path), overrides={"C0": 1e-4, "C1": 1e-4})
        return {name: evaluate(prepared, session_for(prepared), name).metrics
                for name in ("lqr-paper", "bo-paper")}


def sine_claims() -> list[Claim]:
    """Whether 'tracks no worse than the LQR' on a sine tests tracking at all."""
    from furuta_cosim.cosim import evaluate, prepare
    from furuta_cosim.cosim.worker import session_for
    from furuta_cosim.metrics import standing_still
    from furuta_cosim.scenario import load_scenario

    rows = []
    for name in ("sine", "sine-follow"):
        prepared = prepare(load_scenario(name))
        result = evaluate(prepared, session_for(prepared), "lqr-paper")
        ise, still = result.metrics["error.ISE"], standing_still(result.trace)["error.ISE"]
        periods = [sig.params.get("period") for sig in prepared.scenario.reference.signals
                   if sig.kind == "sine"]
        period = periods[0] if periods else None
        rows.append(Claim(f"the LQR follows the {name} reference" + (f" ({period:g} s period)" if period else ""),
                          "not printed (the tracking claims assume it)",
                          f"error.ISE {ise:.4g}; an arm that never moves {still:.4g}",
                          "the LQR's error.ISE below 0.95 of an arm that never moves", below(ise, 0.95 * still),
                          note="a tracking constraint relative to the LQR tests nothing where this fails"))
    return rows


def tuning_claims(spectral: dict, families: dict, budget: int) -> list[Claim]:
    """``spectral``: paper-spectral's summary; ``families``: per tradeoff spec, the lowest
    effort each seed's front reaches at the LQR's tracking (None: no point there)."""
    rows = []
    best = spectral.get("best")
    published = spectral["baselines"].get("bo-paper", {})
    rows.append(Claim(f"BO ({spectral['evaluations']} calls) finds a stable generalized controller",
                      "150 calls, " + PUBLISHED_OBJECTIVE_TEXT,
                      f"stable, objective {best['objective']:.5g}" if best else "none found",
                      "a feasible (stable, margin 0.01) best exists", best is not None))
    value = published.get("objective", float("nan"))
    rows.append(Claim("BO reaches the published controller's objective |Re eig(Abar)|inf",
                      PUBLISHED_OBJECTIVE_TEXT,
                      (f"best {best['objective']:.5g} against the published controller's {value:.5g}"
                       if best else "none found"),
                      "best <= the published controller's value", bool(best) and at_most(best["objective"], value),
                      note=f"Dc searched around the LQR's gains; the objective is degenerate ({READINGS} §3)"))
    import statistics

    def summary(values):
        found = [v for v in values if v is not None]
        if not found:
            return "none", None
        return (f"median {statistics.median(found):.4g} (from {min(found):.4g} to {max(found):.4g}, "
                f"{len(found)} of {len(values)} seeds)"), statistics.median(found)

    general, static = families.get("tradeoff", []), families.get("tradeoff-static", [])
    text_g, median_g = summary(general)
    text_s, median_s = summary(static)
    rows.append(Claim("same tracking with less effort than the LQR (nonlinear plant, co-simulation)",
                      "claimed",
                      f"lowest effort at the LQR's tracking, relative to the LQR: generalized {text_g}; "
                      f"static {text_s}", "the generalized family's median below 1 (the LQR's effort)",
                      median_g is not None and below(median_g, 1.0),
                      note=f"tradeoff fronts, {len(general)} seeds of {budget} calls each"))
    rows.append(Claim("the controller state adds beyond re-weighting the LQR", "claimed (the paper's premise)",
                      f"generalized {text_g}; static (re-weighted LQR) {text_s}",
                      "the generalized family's median below the static family's",
                      median_g is not None and median_s is not None and below(median_g, median_s),
                      note="tradeoff against tradeoff-static, the same seeds and budget"))
    return rows


FAMILY_SEEDS = 5


def _tuned(spec, folder: Path, calls: int, seed: int, workers: int) -> dict:
    from furuta_cosim.tuning.run import tune

    if folder.exists():
        shutil.rmtree(folder)
    return tune(spec, folder, n_calls=calls, seed=seed, workers=workers)


def reproduce(output: str | Path, *, budget: str = "quick", workers: int = 1,
              log: Callable[[str], None] = lambda line: None) -> dict:
    """Check the paper's claims one by one and write the reproduction into ``output``.

    Parameters
    ----------
    output : path
        The folder for ``reproduce.md``, ``reproduce.json``, its HTML page and figures.
    budget : str
        ``"quick"`` (minutes) or ``"full"`` (the paper's budgets).
    workers : int
        Local processes for the tuning claims.
    log : callable
        Takes a line per claim as it is checked.

    Returns
    -------
    dict
        ``{"claims": [...], ...}``: each claim with our value and a verdict.
    """
    from furuta_cosim.fmu.exporter import build_fmu
    from furuta_cosim.report.html import figure, markdown_to_html, page
    from furuta_cosim.scenario import load_scenario
    from furuta_cosim.simulation import simulate_scenario
    from furuta_cosim.tuning.spec import load_spec

    if budget not in BUDGETS:
        from furuta_cosim.errors import ConfigError

        raise ConfigError([f"budget: expected one of {', '.join(BUDGETS)}, got {budget!r}"])
    out = output_folder(output)
    figures = out / "figures"
    log("building the plant FMU")
    fmu = build_fmu("furuta")
    claims = model_claims() + lqr_claims() + published_controller_claims()
    runs = {}
    for name in ("toy-step", "toy-sine", "paper-step", "paper-tracking"):
        log(f"running scenario {name}")
        document, _ = simulate_scenario(load_scenario(name), out / "runs" / name, every=10)
        runs[name] = document
        for path in document["figures"]:  # named relative to the run's folder
            if str(path).endswith(".svg"):
                copy(out / "runs" / name / Path(path).name, figures / Path(path).name)
    claims += toy_claims(runs)
    log("paper-step with the Table's friction")
    claims += pendulum_claims(runs, friction_runs()) + sine_claims()
    calls = BUDGETS[budget]
    log(f"tuning paper-spectral ({calls} calls)")
    spectral = _tuned(load_spec("paper-spectral"), out / "tuning" / "paper-spectral", calls, 0, workers)
    copy(out / "tuning" / "paper-spectral" / "convergence.svg", figures / "convergence-paper-spectral.svg")
    families = {}
    for name in ("tradeoff", "tradeoff-static"):
        spec = load_spec(name)
        for seed in range(FAMILY_SEEDS):
            log(f"tuning {name}, seed {seed} ({calls} calls)")
            document = _tuned(spec, out / "tuning" / f"{name}-seed{seed}", calls, seed, workers)
            reached = (document.get("front") or {}).get("at_baselines", {}).get("lqr-paper") or {}
            effort = reached.get("effort")
            families.setdefault(name, []).append(effort["value"] if effort else None)
    from furuta_cosim.tuning.front import compare

    compare([out / "tuning" / "tradeoff-seed0", out / "tuning" / "tradeoff-static-seed0"], out / "fronts")
    shutil.copyfile(out / "fronts" / "fronts.svg", figures / "fronts-seed0.svg")
    claims += tuning_claims(spectral, families, calls)
    counts = {v: sum(c.verdict == v for c in claims) for v in ("holds", "holds under a reading", "does not hold")}
    md = ["# Reproduction of Solis & Thomas (2021)", "",
          "Generalized State-Feedback Controller Synthesis for Underactuated Systems through "
          "Bayesian Optimization. Every printed number and claim, the project's value, and a "
          f"verdict; the readings are explained in `{READINGS}` of the repository.", "",
          f"Budget: {budget} ({BUDGETS[budget]} tuning calls). Plant FMU: {fmu.name}. "
          + ", ".join(f"{n} {v}" for v, n in counts.items()) + ".", "",
          "| claim or printed number | paper | ours | rule | verdict | note |", "|---|---|---|---|---|---|"]
    md += ["| " + " | ".join(str(c).replace("|", "\u2223") for c in claim.row()) + " |" for claim in claims]
    md += ["", "## Figures", "", "The paper's PDF shows these figures empty; here they are from "
           "the co-simulations above (scenario runs under `runs/`, tunings under `tuning/`)."]
    text = "\n".join(md) + "\n"
    write_text(out / "reproduction.md", text)
    body = markdown_to_html(text) + "".join(figure(p, p.stem) for p in sorted(figures.glob("*.svg")))
    write_text(out / "reproduction.html", page("furuta-cosim: paper reproduction", body))
    document = {"budget": budget, "claims": [c.as_dict() for c in claims], "counts": counts}
    write_text(out / "reproduction.json", dumps(document, indent=1))
    return document
