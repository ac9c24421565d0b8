"""``furuta-cosim reproduce``: the paper, claim by claim, with our value and a verdict.

Each printed number and claim of Solis & Thomas (2021) becomes a row: what the paper says,
what the project computes, and a verdict: ``holds``, ``holds under a reading`` (a reading of
docs/paper-readings.md, named in the row), or ``does not hold``. The runs behind the rows
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
from furuta_cosim.files import output_folder, write_text

BUDGETS = {"quick": 30, "full": 150}
READINGS = "docs/paper-readings.md"
PRINTED_K = [-0.31, -5.26, 70.74, 8.92, 0.17]


@dataclass
class Claim:
    topic: str
    paper: str
    ours: str
    verdict: str            # holds, holds under a reading, does not hold
    note: str = ""

    def row(self) -> list[str]:
        return [self.topic, self.paper, self.ours, self.verdict, self.note]


def _vector(values, digits=4) -> str:
    return "[" + " ".join(f"{v:.{digits}g}" for v in values) + "]"


def _modes(values) -> str:
    shown = []
    for v in values:
        if abs(v.imag) < 1e-12:
            shown.append(f"{v.real:.4g}")
        elif v.imag > 0:
            shown.append(f"{v.real:.4g} ± {v.imag:.4g}j")
    return ", ".join(shown)


def _decimals(printed: float) -> int:
    text = repr(float(printed))
    return 0 if text.endswith(".0") else len(text.split(".")[1])


def _truncate(values, like):
    """``values`` truncated to as many decimals as each printed number has."""
    out = []
    for v, p in zip(values, like):
        decimals = len(repr(float(p)).split(".")[1]) if "." in repr(float(p)) else 0
        scale = 10 ** decimals
        out.append(float(np.trunc(v * scale) / scale))
    return out


def model_claims() -> list[Claim]:
    from furuta_cosim.models import load_model

    printed, derived = load_model("paper-printed"), load_model("derived")
    A, Ad = printed.A, derived.A
    # each derived entry rounded to as many decimals as the printed one has
    rounded = np.array([[round(float(d), _decimals(a)) for d, a in zip(rd, ra)] for rd, ra in zip(Ad, A)])
    mask = np.ones_like(A, bool)
    mask[1, 1] = False
    matching = int(np.sum((rounded == A)[mask]))
    relB = float(np.max(np.abs(derived.B - printed.B) / np.where(np.abs(printed.B) > 0, np.abs(printed.B), 1.0)))
    return [
        Claim("A, linearized plant (Sec. V-B)", "printed 5x5 A", f"{matching} of the {int(mask.sum())} "
              "entries other than A(2,2) round to the printed digits",
              "holds under a reading" if matching == mask.sum() else "does not hold",
              f"one effective gear ratio, friction 1e-3, back-EMF form ({READINGS} §1)"),
        Claim("A(2,2)", f"{A[1, 1]:g}", f"{Ad[1, 1]:.4g}", "does not hold",
              f"no friction value gives the printed entry ({READINGS} §1)"),
        Claim("B, linearized plant", _vector(printed.B.ravel()), _vector(derived.B.ravel()),
              "holds" if relB < 0.01 else "holds under a reading", f"largest difference {relB:.2%}"),
    ]


def lqr_claims() -> list[Claim]:
    from furuta_cosim.design import lqr
    from furuta_cosim.models import load_model

    model = load_model("paper-printed")
    discrete = lqr(model, np.diag(PAPER_Q), np.diag([PAPER_R]), PAPER_PERIOD).Dc[0]
    continuous = lqr(model, np.diag(PAPER_Q), np.diag([PAPER_R]), None).Dc[0]
    truncated = _truncate(discrete, PRINTED_K)
    same = truncated == PRINTED_K
    worst = float(np.max(np.abs(continuous - PRINTED_K) / np.abs(PRINTED_K)))
    return [
        Claim("K, LQR with Q = diag(1, 10, 100, 10, 1), R = 10", _vector(PRINTED_K),
              _vector(discrete, 6) + " (discrete LQR at 2 ms)",
              "holds under a reading" if same else "does not hold",
              f"truncates to the printed digits{'' if same else ' : NOT'}; the printed K is a discrete "
              f"LQR at 2 ms ({READINGS} §2)"),
        Claim("K as a continuous LQR", _vector(PRINTED_K), _vector(continuous, 5), "does not hold",
              f"up to {worst:.1%} away: the printed gain is not the continuous design"),
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
                          f"{'stable' if analysis.stable else 'UNSTABLE'}; slowest mode "
                          f"{dominant.eigenvalue.real:.4g} ± {abs(dominant.eigenvalue.imag):.4g}j",
                          "holds" if analysis.stable else "does not hold",
                          f"Bc = 0: the controller state never sees the plant ({READINGS} §3)"
                          if model_name == "paper-printed" else
                          f"stability turns on the pendulum friction alone ({READINGS} §3)"))
    model = load_model("paper-printed")
    value = float(np.max(np.abs(analyze(model, check_fits(cfile, model).controller).eigenvalues.real)))
    rows.append(Claim("BO objective |Re eig(Abar)|inf of the published controller", "minimized by BO",
                      f"{value:.5g} (the fastest mode, not the slowest)", "holds under a reading",
                      f"implemented exactly as stated; it is degenerate ({READINGS} §3)"))
    return rows


def toy_claims(runs: dict) -> list[Claim]:
    from furuta_cosim.controllers import check_fits, load_controller
    from furuta_cosim.design import analyze
    from furuta_cosim.models import load_model

    model = load_model("toy")
    rows = []
    gen = check_fits(load_controller("toy-generalized"), model)
    cls = check_fits(load_controller("toy-classical"), model)
    eig = np.sort(np.abs(analyze(model, gen.controller).eigenvalues))
    eig_classical = np.sort(np.abs(analyze(model, cls.controller).eigenvalues))
    rows.append(Claim("toy: eig(Abar) of the generalized controller", "{0.5, 0.59, 0.8}",
                      "{" + ", ".join(f"{v:.4g}" for v in eig) + "}",
                      "holds" if np.allclose(eig, [0.5, 0.59, 0.8], atol=5e-3) else "does not hold",
                      f"computed directly; the paper's block formula is not general ({READINGS} §4)"))
    rows.append(Claim("toy: eig(A - BK) of the classical controller", "{0.5, 0.8}",
                      "{" + ", ".join(f"{v:.4g}" for v in eig_classical) + "}",
                      "holds" if np.allclose(eig_classical, [0.5, 0.8], atol=5e-3) else "does not hold"))
    rows.append(Claim("toy: prefilters F", "2.0 (classical), 1.3667 (generalized)",
                      f"{cls.F:.5g}, {gen.F:.5g}",
                      "holds" if abs(cls.F - 2.0) < 1e-3 and abs(gen.F - 1.3667) < 1e-3 else "does not hold",
                      f"the discrete DC-gain formula ({READINGS} §4)"))
    step, sine = runs["toy-step"]["controllers"], runs["toy-sine"]["controllers"]
    kick = "the first kick at the step"
    peak_c, peak_g = sine["toy-classical"]["metrics"]["u.peak_abs"], sine["toy-generalized"]["metrics"]["u.peak_abs"]
    rms = {n: sine[n]["metrics"].get("error.RMS") for n in sine}
    rows.append(Claim("toy: the generalized controller tracks as well with less effort", "claimed (figures)",
                      f"step: peak |u| {step['toy-classical']['metrics']['u.peak_abs']:.4g} vs "
                      f"{step['toy-generalized']['metrics']['u.peak_abs']:.4g}; sine: peak |u| {peak_c:.4g} vs "
                      f"{peak_g:.4g}, RMS error {rms['toy-classical']:.4g} vs {rms['toy-generalized']:.4g} "
                      "(classical vs generalized)", "does not hold",
                      f"only {kick} and the sine's peak are lower; tracking is worse ({READINGS} §4)"))
    return rows


def pendulum_claims(runs: dict) -> list[Claim]:
    step = runs["paper-step"]["controllers"]
    lqr, bo = step["lqr-paper"]["metrics"], step["bo-paper"]["metrics"]
    settled = lqr.get("theta1.SettlingTime")
    return [
        Claim("LQR brings the pendulum back from 0.1 rad (nonlinear plant)", "figure (empty in the PDF)",
              f"settles in {settled:.3g} s, peak |u| {lqr['u.peak_abs']:.3g} V", "holds"),
        Claim("published BO controller on the nonlinear calibrated plant", "figure (empty in the PDF)",
              f"theta1 reaches {bo['theta1.max_abs']:.3g} rad, RMS voltage {bo['u.rms']:.3g} V",
              "does not hold" if bo["theta1.max_abs"] > 0.1 else "holds",
              f"unstable with friction 1e-3; rings but recovers with 1e-4 ({READINGS} §5)"),
    ]


def tuning_claims(documents: dict) -> list[Claim]:
    spectral, effort = documents["paper-spectral"], documents["effort"]
    rows = []
    best = spectral.get("best")
    rows.append(Claim(f"BO (GP + EI, {spectral['evaluations']} calls) finds a stable generalized controller",
                      "150 calls, Ac = -100, Bc = 0, Cc = -0.5", "stable, objective "
                      f"{best['objective']:.5g}" if best else "none found",
                      "holds" if best else "does not hold",
                      "our optimum of the stated objective differs from the published controller: the "
                      f"objective is degenerate ({READINGS} §3)"))
    lqr = effort["baselines"].get("lqr-paper", {})
    tuned = effort.get("best")
    if tuned and lqr.get("feasible"):
        change = tuned["objective"] / lqr["objective"] - 1.0
        text = (f"effort objective {tuned['objective']:.4g} against the LQR's {lqr['objective']:.4g} "
                f"({change:+.1%})")
        holds = change < 0
    else:
        text, holds = "no feasible tuned controller", False
    rows.append(Claim("same tracking with less effort than LQR (pendulum, co-simulation)", "claimed",
                      text, "holds" if holds else "does not hold",
                      f"tuning 'effort', {effort['evaluations']} evaluations, ISE within +5 % of LQR's"))
    return rows


def reproduce(output: str | Path, *, budget: str = "quick", workers: int = 1,
              log: Callable[[str], None] = lambda line: None) -> dict:
    """Run the whole reproduction into ``output``; return ``{"claims": [...], ...}``."""
    from furuta_cosim.fmu.exporter import build_fmu
    from furuta_cosim.report.html import figure, markdown_to_html, page
    from furuta_cosim.scenario import load_scenario
    from furuta_cosim.simulation import simulate_scenario
    from furuta_cosim.tuning.run import tune
    from furuta_cosim.tuning.spec import load_spec

    if budget not in BUDGETS:
        from furuta_cosim.errors import ConfigError

        raise ConfigError([f"--budget: expected one of {', '.join(BUDGETS)}, got {budget!r}"])
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
        for path in document["figures"]:
            if str(path).endswith(".svg"):
                figures.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(path, figures / Path(path).name)
    claims += toy_claims(runs) + pendulum_claims(runs)
    documents = {}
    for name in ("paper-spectral", "effort"):
        log(f"tuning {name} ({BUDGETS[budget]} calls)")
        run_dir = out / "tuning" / name
        if run_dir.exists():
            shutil.rmtree(run_dir)
        documents[name] = tune(load_spec(name), run_dir, n_calls=BUDGETS[budget], workers=workers)
        svg = run_dir / "convergence.svg"
        if svg.is_file():
            shutil.copyfile(svg, figures / f"convergence-{name}.svg")
    claims += tuning_claims(documents)
    counts = {v: sum(c.verdict == v for c in claims) for v in ("holds", "holds under a reading", "does not hold")}
    md = ["# Reproduction of Solis & Thomas (2021)", "",
          "Generalized State-Feedback Controller Synthesis for Underactuated Systems through "
          "Bayesian Optimization. Every printed number and claim, the project's value, and a "
          f"verdict; the readings are explained in `{READINGS}` of the repository.", "",
          f"Budget: {budget} ({BUDGETS[budget]} tuning calls). Plant FMU: {fmu.name}. "
          + ", ".join(f"{n} {v}" for v, n in counts.items()) + ".", "",
          "| claim or printed number | paper | ours | verdict | note |", "|---|---|---|---|---|"]
    md += ["| " + " | ".join(str(c).replace("|", "\u2223") for c in claim.row()) + " |" for claim in claims]
    md += ["", "## Figures", "", "The paper's PDF shows these figures empty; here they are from "
           "the co-simulations above (scenario runs under `runs/`, tunings under `tuning/`)."]
    text = "\n".join(md) + "\n"
    write_text(out / "reproduction.md", text)
    body = markdown_to_html(text) + "".join(figure(p, p.stem) for p in sorted(figures.glob("*.svg")))
    write_text(out / "reproduction.html", page("furuta-cosim: paper reproduction", body))
    document = {"budget": budget, "claims": [c.__dict__ for c in claims], "counts": counts}
    write_text(out / "reproduction.json", dumps(document, indent=1))
    return document
