"""A user's plant folder (model.py + model.c) becomes FMUs, and its mistakes are one line at
their file and line. The shipped example: Quanser's IP02 cart-pole (scenarios/cart-pole/)."""

import shutil
from pathlib import Path

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from furuta_cosim.cli import main
from furuta_cosim.errors import ConfigError
from furuta_cosim.fmu.check import validate
from furuta_cosim.fmu.exporter import build_fmu, declaration
from furuta_cosim.fmu.linearize import linearize
from furuta_cosim.fmu.plants import folder_plant, load_plant
from furuta_cosim.fmu.session import PlantSession

EXAMPLE = Path(__file__).resolve().parent.parent / "scenarios" / "cart-pole"
FOLDER = EXAMPLE / "plant"
IP02 = EXAMPLE / "plants" / "ip02.yaml"

# the manuals' values (the declaration's defaults), written here again on purpose: the test's
# equations below are an independent transcription of the cart-pole, not the model's code
P = dict(M_c=0.57, J_m=3.9e-7, K_g=3.71, eta_g=1.0, eta_m=1.0, K_t=7.67e-3, K_m=7.67e-3,
         R_m=2.6, r_mp=6.35e-3, B_eq=4.3, M_p=0.230, l_p=0.3302, J_p=7.88e-3, B_p=0.0024, g=9.81)


def _cart_pole(t, state, V):
    """Newton-Euler on the cart and the pendulum, separately: the pendulum's reaction on the
    cart is eliminated by hand (the model uses Lagrange's equations in matrix form)."""
    x, dx, a, da = state
    M = P["M_c"] + P["eta_g"] * P["K_g"] ** 2 * P["J_m"] / P["r_mp"] ** 2
    F = P["eta_g"] * P["K_g"] * P["eta_m"] * P["K_t"] * (V - P["K_g"] * P["K_m"] * dx / P["r_mp"]) / (P["R_m"] * P["r_mp"])
    m, l, J, g = P["M_p"], P["l_p"], P["J_p"], P["g"]
    # pendulum about its pivot on an accelerating cart: (J + m l^2) a'' = m g l sin a - m l cos a x'' - B_p a'
    # cart: M x'' = F - B_eq x' - H, with H = m (x'' + l cos a a'' - l sin a a'^2), the pendulum's pull
    # two linear equations in x'', a'':
    lhs = np.array([[M + m, m * l * np.cos(a)], [m * l * np.cos(a), J + m * l * l]])
    rhs = np.array([F - P["B_eq"] * dx + m * l * np.sin(a) * da * da, m * g * l * np.sin(a) - P["B_p"] * da])
    ddx, dda = np.linalg.solve(lhs, rhs)
    return [dx, ddx, da, dda]


def _linear_by_hand():
    """The linear model at the upright rest, derived on paper: with D = (M + m) Jt - (m l)^2,
    Jt = J + m l^2, and the motor's force F = a V - b x' (a = eta K_g eta_m K_t / (R_m r_mp),
    b = a K_g K_m / r_mp):"""
    m, l, J, g = P["M_p"], P["l_p"], P["J_p"], P["g"]
    M = P["M_c"] + P["eta_g"] * P["K_g"] ** 2 * P["J_m"] / P["r_mp"] ** 2
    a = P["eta_g"] * P["K_g"] * P["eta_m"] * P["K_t"] / (P["R_m"] * P["r_mp"])
    b = a * P["K_g"] * P["K_m"] / P["r_mp"]
    Jt = J + m * l * l
    D = (M + m) * Jt - (m * l) ** 2
    A = np.zeros((4, 4))
    A[0, 1] = A[2, 3] = 1.0
    A[1] = [0.0, -Jt * (b + P["B_eq"]) / D, -(m * l) ** 2 * g / D, m * l * P["B_p"] / D]
    A[3] = [0.0, m * l * (b + P["B_eq"]) / D, (M + m) * m * g * l / D, -(M + m) * P["B_p"] / D]
    B = np.array([[0.0], [Jt * a / D], [0.0], [-m * l * a / D]])
    return A, B


def test_the_example_folder_builds_fmi2_and_fmi3_fmus_that_pass_every_check():
    for version in ("2.0", "3.0"):
        fmu = build_fmu(folder_plant(FOLDER), fmi_version=version)
        findings = validate(fmu)
        assert findings and all(f.ok for f in findings), [f for f in findings if not f.ok]
        assert any(f.check == "fmpy validate" for f in findings)


def test_its_fmu_follows_an_independent_integration_of_the_cart_pole():
    start = [0.05, -0.1, 0.2, 0.3]  # off the rest: the nonlinear terms count
    V = 1.5
    with PlantSession.open(build_fmu(load_plant(IP02))) as session:
        session.reset({"x_c_start": start[0], "dx_c_start": start[1], "alpha_start": start[2],
                       "dalpha_start": start[3], "n_substeps": 20})
        session.set_io(["V"], ["x_c", "dx_c", "alpha", "dalpha"])
        period, steps = 0.002, 250
        fmu = np.array([session.step([V], period) for _ in range(steps)])
    times = period * np.arange(1, steps + 1)
    truth = solve_ivp(_cart_pole, (0.0, times[-1]), start, args=(V,), t_eval=times, rtol=1e-11, atol=1e-12).y.T
    assert np.max(np.abs(fmu - truth)) < 1e-8, np.max(np.abs(fmu - truth))
    assert abs(truth[-1, 2] - start[2]) > 0.1       # it moved: the pendulum falls away from upright


def test_its_linearization_equals_the_linear_model_derived_by_hand():
    result = linearize(build_fmu(load_plant(IP02)), inputs={"V": 0.0})
    assert list(result.states) == ["x_c", "dx_c", "alpha", "dalpha"]
    A, B = _linear_by_hand()
    np.testing.assert_allclose(result.A, A, rtol=1e-6, atol=1e-9)
    np.testing.assert_allclose(result.B, B, rtol=1e-6, atol=1e-9)
    assert max(np.linalg.eigvals(A).real) > 4.0   # the upright pendulum: unstable


def test_the_declaration_names_the_plant_s_own_variables():
    model = declaration(load_plant(IP02))
    assert [s.name for s in model.states] == ["x_c", "dx_c", "alpha", "dalpha"]
    assert model.measured == ["x_c", "alpha"]
    units = {v.name: v.unit for v in model.reals}
    assert units["x_c"] == "m" and units["alpha"] == "rad" and units["V"] == "V"


def test_build_fmu_takes_a_folder(tmp_path, capsys):
    assert main(["build-fmu", str(FOLDER), "-o", str(tmp_path), "--fmi-version", "3.0"]) == 0
    assert (tmp_path / "CartPole.fmu").is_file()


# --- a folder with a mistake: one line, at the file and line of the mistake ----------------

def _copy(tmp_path) -> Path:
    folder = tmp_path / "mine"
    shutil.copytree(FOLDER, folder)
    return folder


def _line_of(path: Path, text: str) -> int:
    return next(k for k, line in enumerate(path.read_text().splitlines(), start=1) if text in line)


def _one_line(call) -> str:
    with pytest.raises(ConfigError) as caught:
        call()
    assert len(caught.value.problems) == 1, caught.value.problems
    message = caught.value.problems[0]
    assert "\n" not in message
    return message


def test_a_state_without_a_unit_is_named_at_its_line(tmp_path):
    folder = _copy(tmp_path)
    model_py = folder / "model.py"
    model_py.write_text(model_py.read_text().replace('"alpha", 0.0, "rad",', '"alpha", 0.0, "",'))
    message = _one_line(lambda: build_fmu(folder_plant(folder)))
    line = _line_of(model_py, 'register_state("alpha"')
    assert message.startswith(f"{model_py}:{line}: state 'alpha' has no unit")


def test_a_parameter_out_of_its_range_is_named_at_its_line(tmp_path):
    folder = _copy(tmp_path)
    plant = tmp_path / "mine.yaml"
    plant.write_text("model: mine\nparameters:\n  V_max: 10\n  M_p: -0.2\n")
    message = _one_line(lambda: build_fmu(load_plant(plant)))
    assert message == f"{plant}:4: parameters.M_p: must be > 0, got -0.2"
    plant.write_text("model: mine\nparameters:\n  eta_g: 1.2\n")
    assert _one_line(lambda: build_fmu(load_plant(plant))) == f"{plant}:3: parameters.eta_g: must be <= 1, got 1.2"
    # a default out of its own range: the declaration's line
    model_py = folder / "model.py"
    model_py.write_text(model_py.read_text().replace('"B_p", 0.0024,', '"B_p", -0.0024,'))
    message = _one_line(lambda: build_fmu(folder_plant(folder)))
    line = _line_of(model_py, '"B_p", -0.0024')
    assert message.startswith(f"{model_py}:{line}: ")
    assert "B_p" in message and ">= 0" in message


def test_equations_that_do_not_compile_are_named_at_their_line(tmp_path):
    folder = _copy(tmp_path)
    model_c = folder / "model.c"
    model_c.write_text(model_c.read_text().replace("det = m11 * m22 - m12 * m12;", "det = m11 * m22 - m13;"))
    message = _one_line(lambda: build_fmu(folder_plant(folder)))
    assert message.startswith(f"{model_c}:{_line_of(model_c, 'det = m11 * m22 - m13;')}: does not compile: ")
    assert "m13" in message


def test_a_declaration_that_does_not_run_is_named_at_its_line(tmp_path):
    folder = _copy(tmp_path)
    model_py = folder / "model.py"
    text = model_py.read_text()
    model_py.write_text(text.replace('    model.substeps = "n_substeps"', '    model.substeps = n_substep'))
    message = _one_line(lambda: build_fmu(folder_plant(folder)))
    assert message.startswith(f"{model_py}:{_line_of(model_py, 'model.substeps = n_substep')}: NameError")
    model_py.write_text(text.replace("def declare(parameters):", "def declare(parameters)"))
    message = _one_line(lambda: build_fmu(folder_plant(folder)))
    assert message.startswith(f"{model_py}:{_line_of(model_py, 'def declare(parameters)')}: SyntaxError")


def test_a_folder_without_its_equations_says_what_a_plant_folder_holds(tmp_path):
    folder = _copy(tmp_path)
    (folder / "model.c").unlink()
    message = _one_line(lambda: folder_plant(folder))
    assert "model.c missing" in message and "new-plant" in message
    plant = tmp_path / "mine.yaml"
    plant.write_text("model: mine\n")
    assert "plant.model" not in _one_line(lambda: load_plant(plant))


# --- new-plant: a folder to start from ---------------------------------------------------

def test_new_plant_writes_a_folder_that_builds_designs_and_simulates(tmp_path, capsys, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert main(["new-plant", "my-spring"]) == 0
    assert sorted(p.name for p in (tmp_path / "my-spring").iterdir()) == ["model.c", "model.py", "plant.yaml", "step.yaml"]
    assert "simulate my-spring/step.yaml" in capsys.readouterr().out
    assert declaration(folder_plant("my-spring")).identifier == "MySpring"
    assert main(["design", "lqr", "--plant", "my-spring/plant.yaml", "--continuous", "-o", "my-spring/lqr.yaml"]) == 0
    assert main(["simulate", "my-spring/step.yaml", "-o", "out", "--json"]) == 0
    import json

    metrics = json.loads((tmp_path / "out" / "metrics.json").read_text())
    run = metrics["controllers"]["lqr"]
    assert run["tracked"] == "x" and run["input"] == "F" and run["units"]["x"] == "m"
    assert run["metrics"]["x.SteadyStateValue"] == pytest.approx(0.1, rel=1e-3)   # the prefilter's work
    capsys.readouterr()
    assert main(["new-plant", "my-spring"]) == 2
    assert "my-spring: exists already" in capsys.readouterr().err
    assert main(["new-plant", "9lives"]) == 2
    assert "starts with a letter" in capsys.readouterr().err
    assert not list(tmp_path.glob(".*partial*"))
    assert not (tmp_path / "my-spring" / "__pycache__").exists()   # running the declaration wrote nothing there
