"""`furuta-cosim design lqr` and `analyze`: JSON results, words, and bad input."""

import json

import numpy as np
import pytest

from helpers import run_cli as run


def test_design_lqr_json_gives_the_printed_gain(capsys):
    code, out, _ = run(capsys, "design", "lqr", "--json")
    result = json.loads(out)
    assert code == 0 and result["time"] == "discrete" and result["period"] == 0.002
    assert (np.trunc(np.array(result["K"]) * 100) / 100).tolist() == [-0.31, -5.26, 70.74, 8.92, 0.17]
    assert len(result["closed_loop_eigenvalues"]) == 5 and result["stable"]


def test_design_lqr_continuous_with_custom_weights(capsys):
    code, out, _ = run(capsys, "design", "lqr", "--continuous", "--Q", "1", "10", "100", "10", "1",
                       "--R", "10", "--json")
    K = json.loads(out)["K"]
    np.testing.assert_allclose(K, [-0.3162, -5.3118, 71.506, 9.0187, 0.1834], rtol=1e-3)
    code, out, _ = run(capsys, "design", "lqr", "--continuous", "--R", "1", "--json")
    assert abs(json.loads(out)["K"][0]) > abs(K[0])  # cheaper input, stronger gain


def test_design_writes_a_file_that_analyze_reads(tmp_path, capsys):
    target = tmp_path / "mine.yaml"
    code, _, err = run(capsys, "design", "lqr", "--model", "derived", "-o", str(target))
    assert code == 0 and "wrote" in err
    code, out, _ = run(capsys, "analyze", str(target), "--json")
    result = json.loads(out)
    assert code == 0 and result["stable"] and result["model"] == "derived"
    assert result["spectral_radius"] < 1.0 and "spectral_abscissa" not in result


def test_analyze_says_the_bo_controller_is_unstable_on_the_calibrated_plant(capsys):
    code, out, _ = run(capsys, "analyze", "bo-paper", "--model", "derived")
    assert code == 1
    assert "The closed loop is UNSTABLE: the mode 0.1851 ± 7.854j grows" in out
    assert "Sampled at 2 ms with zero-order hold the loop is UNSTABLE" in out
    code, out, _ = run(capsys, "analyze", "bo-paper", "--json")
    result = json.loads(out)
    assert code == 0 and result["stable"] and result["spectral_abscissa"] == pytest.approx(-0.1053, abs=1e-3)
    assert result["sampled"]["stable"] and result["prefilter"]["F"] == pytest.approx(-20.96)


BAD_CONTROLLERS = {
    "wrong-dimensions": ("type: static\ntime: discrete\nperiod: 0.002\nK: [1, 2, 3, 4]\nmodel: paper-printed\n",
                         "K: expected 5 values per row (model paper-printed has 5 states), got 4"),
    "non-finite": ("type: static\ntime: discrete\nperiod: 0.002\nK: [.nan, 1, 1, 1, 1]\nmodel: paper-printed\n",
                   "K[0][0]: must be finite, got nan"),
    "zero-period": ("type: static\ntime: discrete\nperiod: 0\nK: [1, 1, 1, 1, 1]\nmodel: paper-printed\n",
                    "period: must be > 0, got 0"),
    "singular-prefilter": ("type: static\ntime: discrete\nperiod: 0.002\nK: [-0.31, -5.26, 70.74, 8.92, 0.17]\n"
                           "model: paper-printed\nprefilter: {output: dtheta0}\n",
                           "prefilter.output: prefilter: the DC gain from r to dtheta0 is"),
    "generalized-shapes": ("type: generalized\ntime: continuous\nAc: [[1, 0]]\nBc: [[0, 0, 0, 0, 0]]\n"
                           "Cc: [[1]]\nDc: [[1, 1, 1, 1, 1]]\nmodel: paper-printed\n",
                           "Ac: must be square, got 1x2"),
    # an empty row was a traceback (max() of an empty sequence) in every matrix
    "empty-row-K": ("type: static\ntime: discrete\nperiod: 0.002\nK: [[]]\nmodel: paper-printed\n",
                    "K: expected a matrix with at least one entry in each row, got an empty row"),
    "empty-row-Bc": ("type: generalized\ntime: continuous\nAc: [[-1]]\nBc: [[]]\n"
                     "Cc: [[1]]\nDc: [[1, 1, 1, 1, 1]]\nmodel: paper-printed\n",
                     "Bc: expected a matrix with at least one entry in each row, got an empty row"),
    "unknown-key": ("type: static\ntime: discrete\nperiod: 0.002\nK: [1, 1, 1, 1, 1]\ngain: 3\n",
                    "gain: unknown key"),
}


@pytest.mark.parametrize("case", sorted(BAD_CONTROLLERS))
def test_bad_controller_files_give_one_clear_line_and_exit_2(tmp_path, capsys, case):
    text, expected = BAD_CONTROLLERS[case]
    path = tmp_path / f"{case}.yaml"
    path.write_text(text)
    code, out, err = run(capsys, "analyze", str(path), "--model", "paper-printed")
    assert code == 2 and out == ""
    assert err.startswith(f"error: {path}: ") and expected in err, err
    assert "Traceback" not in err


def test_unstabilizable_model_file_is_named(tmp_path, capsys):
    plant = tmp_path / "stuck.yaml"
    plant.write_text("model: linear\ntime: continuous\nA: [[1, 0], [0, -1]]\nB: [[0], [1]]\nC: [[1, 1]]\n")
    code, _, err = run(capsys, "design", "lqr", "--model", str(plant), "--continuous")
    assert code == 2
    assert err.startswith(f"error: {plant}: A, B: (A, B) of stuck is not stabilizable: mode(s) 1")


def test_bad_period_and_weights_exit_2(capsys):
    code, _, err = run(capsys, "design", "lqr", "--period", "0")
    assert code == 2 and err.strip() == "error: --period: must be > 0, got 0.0"
    code, _, err = run(capsys, "design", "lqr", "--Q", "1", "2")
    assert code == 2 and "--Q: expected 5 diagonal values or 25 entries, got 2" in err


def test_list_shows_every_shipped_file_with_its_description(capsys):
    code, out, _ = run(capsys, "list")
    assert code == 0
    for name in ("paper-calibrated", "table-literal", "toy", "paper-printed", "lqr-paper", "bo-paper",
                 "toy-classical", "toy-generalized", "paper-step", "noise-kalman", "toy-sine"):
        assert f"  {name} " in out
    assert "the paper's BO-tuned generalized controller" in out


@pytest.mark.parametrize("argv, expected", [
    (["--track", "dtheta0"], "error: --track dtheta0: prefilter: the DC gain from r to dtheta0 is"),
    (["--track", "phi"], "error: --track phi: model paper-printed has no output or state 'phi'"),
    (["--R", "-1"], "error: --R: R must be positive definite"),
    (["--Q", "1", "1", "1", "1", "-1"], "error: --Q: Q must be positive semi-definite"),
    (["--model", "toy", "--R", "1", "2"], "error: --R: expected 1 value, got 2"),
])
def test_design_flags_with_problems_are_named(capsys, argv, expected):
    code, out, err = run(capsys, "design", "lqr", *argv)
    assert code == 2 and out == "" and "Traceback" not in err
    assert err.startswith(expected), err


def test_a_single_weight_value_scales_the_identity(capsys):
    _, out, _ = run(capsys, "design", "lqr", "--continuous", "--Q", "1", "--R", "1", "--json")
    _, reference, _ = run(capsys, "design", "lqr", "--continuous", "--Q", "1", "1", "1", "1", "1",
                          "--R", "1", "--json")
    assert json.loads(out)["K"] == json.loads(reference)["K"]
