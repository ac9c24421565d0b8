"""Plant variants drawn from a fit: the covariance (correlated pairs move together), a seeded
space-filling design, the fit's bounds; a damaged fit.json is one line per problem."""

import json
from pathlib import Path

import numpy as np
import pytest

from furuta_cosim.errors import ConfigError
from furuta_cosim.identify.variants import read_fit, variants_from_fit

from helpers import fit_folder


def _fit(folder: Path, rho: float = 0.95, **change) -> Path:
    parameters = change.pop("parameters", {
        "R_a": {"value": 7.6, "stderr": 0.05, "bounds": [1.0, 30.0]},
        "M_f": {"value": 0.042, "stderr": 0.001, "bounds": [0.005, 0.2]},
        "free-swing.theta1": {"value": 3.2, "stderr": 0.001, "bounds": [3.1, 3.3]}})
    correlation = change.pop("correlation", {"names": ["R_a", "M_f", "free-swing.theta1"],
                                             "matrix": [[1.0, rho, 0.0], [rho, 1.0, 0.0], [0.0, 0.0, 1.0]]})
    return fit_folder(folder, parameters, correlation, **change)


def test_variants_follow_the_fits_covariance(tmp_path):
    found = variants_from_fit(_fit(tmp_path), 64, seed=0)
    assert found[0] == {} and len(found) == 65
    assert all(set(v) == {"R_a", "M_f"} for v in found[1:])  # initial states are not the plant's
    R = np.array([v["R_a"] for v in found[1:]])
    M = np.array([v["M_f"] for v in found[1:]])
    assert np.mean(R) == pytest.approx(7.6, abs=0.01) and np.std(R) == pytest.approx(0.05, rel=0.15)
    assert np.corrcoef(R, M)[0, 1] == pytest.approx(0.95, abs=0.03)  # they move together
    assert variants_from_fit(_fit(tmp_path), 8, seed=0) == variants_from_fit(_fit(tmp_path), 8, seed=0)
    assert variants_from_fit(_fit(tmp_path), 8, seed=1) != variants_from_fit(_fit(tmp_path), 8, seed=0)


def test_a_parameter_s_reach_widens_its_spread_as_it_widens_its_interval(tmp_path):
    """A reach of 1.96 x 0.05 (the counted start angles', identify/reach.py) doubles R_a's
    spread; the correlation stays."""
    parameters = {"R_a": {"value": 7.6, "stderr": 0.05, "reach": 1.959963984540054 * 0.05, "bounds": [1.0, 30.0]},
                  "M_f": {"value": 0.042, "stderr": 0.001, "reach": 0.0, "bounds": [0.005, 0.2]}}
    names, _, covariance, _ = read_fit(_fit(tmp_path, parameters=parameters))
    assert names == ["R_a", "M_f"]
    assert np.sqrt(np.diag(covariance)) == pytest.approx([0.1, 0.001], rel=1e-12)
    assert covariance[0, 1] / np.sqrt(covariance[0, 0] * covariance[1, 1]) == pytest.approx(0.95)
    parameters["R_a"]["reach"] = -1.0
    with pytest.raises(ConfigError, match=r"parameters.R_a.reach: expected a finite number >= 0"):
        read_fit(_fit(tmp_path, parameters=parameters))


def test_a_singular_covariance_and_the_bounds_are_honoured(tmp_path):
    wide = _fit(tmp_path, rho=1.0, parameters={
        "R_a": {"value": 1.05, "stderr": 1.0, "bounds": [1.0, 30.0]},
        "M_f": {"value": 0.042, "stderr": 0.001, "bounds": [0.005, 0.2]}})
    found = variants_from_fit(wide, 16, seed=0)
    assert min(v["R_a"] for v in found[1:]) == 1.0  # clipped at the fit's bound
    assert all(np.isfinite(list(v.values())).all() for v in found[1:])


@pytest.mark.parametrize("change, expected", [
    ({"parameters": {}}, "parameters: expected the fitted parameters"),
    ({"correlation": {"names": ["R_a"]}}, "correlation: expected names and matrix"),
    ({"correlation": {"names": ["R_a", "M_f", "free-swing.theta1"], "matrix": [[1.0]]}},
     "correlation.matrix: expected 3x3 finite numbers"),
    ({"parameters": {"R_a": {"value": float("nan"), "stderr": 0.1, "bounds": [1, 30]},
                     "M_f": {"value": 0.042, "stderr": 0.001, "bounds": [0.005, 0.2]}}},
     "parameters.R_a: expected value, stderr >= 0 and bounds"),
    ({"correlation": {"names": ["R_a", "M_f", "free-swing.theta1"],
                      "matrix": [[1.0, 2.0, 0.0], [2.0, 1.0, 0.0], [0.0, 0.0, 1.0]]}},
     "not a correlation matrix"),
])
def test_a_damaged_fit_is_named(tmp_path, change, expected):
    with pytest.raises(ConfigError, match=expected):
        read_fit(_fit(tmp_path, **change))


def test_not_json_is_one_line(tmp_path):
    path = tmp_path / "fit.json"
    path.write_bytes(b"\xff\x00 not json")
    with pytest.raises(ConfigError, match="not JSON"):
        read_fit(path)


def test_a_spec_draws_its_variants_and_its_plant_from_the_fit(tmp_path):
    from furuta_cosim.tuning.spec import load_spec

    fit = _fit(tmp_path)
    spec = tmp_path / "robust.yaml"
    text = (Path(__file__).resolve().parent.parent / "scenarios" / "tuning" / "effort.yaml").read_text()
    (tmp_path / "controllers").mkdir()
    import shutil

    shutil.copy(Path(__file__).resolve().parent.parent / "scenarios" / "controllers" / "lqr-paper.yaml",
                tmp_path / "controllers")
    spec.write_text(text + f"variants: {{from_fit: {fit.name}, samples: 4, seed: 3}}\n")
    loaded = load_spec(spec)
    assert len(loaded.variants) == 5 and loaded.variants[0] == ()
    assert loaded.plant.endswith("plant.yaml") and loaded.model.startswith("derived:")
    spec.write_text(text + "variants: {from_fit: nowhere/fit.json}\n")
    with pytest.raises(ConfigError, match="variants.from_fit: .*nowhere/fit.json: expected the fit.json"):
        load_spec(spec)


@pytest.mark.slow
def test_a_robust_tuning_reports_each_controllers_worst_variant(tmp_path, capsys):
    from helpers import run_cli

    root = Path(__file__).resolve().parent.parent
    fit = _fit(tmp_path)
    (tmp_path / "controllers").mkdir()
    import shutil

    shutil.copy(root / "scenarios" / "controllers" / "lqr-paper.yaml", tmp_path / "controllers")
    spec = tmp_path / "robust.yaml"
    spec.write_text((root / "scenarios" / "tuning" / "effort.yaml").read_text()
                    + f"variants: {{from_fit: {fit.name}, samples: 2, seed: 0}}\n")
    code, out, err = run_cli(capsys, "tune", str(spec), "--n-calls", "4", "--workers", "1",
                             "-o", str(tmp_path / "run"), "--json")
    assert code == 0, err
    variants = json.loads(out)["variants"]
    lqr = variants["lqr-paper-on-plant"]
    assert len(lqr["scores"]) == 3
    # each term is relative to this LQR on the same run: it scores 1 + 0.1 on every variant
    assert lqr["worst"] == pytest.approx(1.1, rel=1e-9) and lqr["best"] == pytest.approx(1.1, rel=1e-9)
    tuned = variants["tuned"]
    assert tuned["worst"] == max(tuned["scores"]) and tuned["best"] == min(tuned["scores"])
    assert "Over the 3 plant variants" in (tmp_path / "run" / "summary.md").read_text()
