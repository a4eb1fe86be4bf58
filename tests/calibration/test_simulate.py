import json

import cv2

from lfstudio.calibration.simulate import simulate


def test_simulation_reproduces_the_papers_figures_within_tolerance():
    out = simulate(trials=6, pp_shift_px=50.0, seed=3)
    fixed = out["without_principal_point"]
    # RMS floor: 0.5 px per feature (0.71 px for a difference) plus 80 µm position noise
    assert 0.7 < fixed["residual_px"]["mean"] < 0.9
    assert 0.55 < fixed["residual_mean_abs_px"]["mean"] < 0.72     # the paper: 0.66–0.71 "average"
    assert fixed["true_residual_px"]["mean"] < 0.3
    assert fixed["rotation_error_deg"]["median"] < 0.06
    assert out["residual_px"] == fixed["residual_px"]
    assert "with_principal_point" in out and out["failures"] == 0


def test_cli_json_and_sweep_plot(run_cli, tmp_path):
    proc = run_cli("simulate-calibration", "--trials", "3", "--pp-shift-px", "20", "--json", "--seed", "1")
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    assert set(out["residual_px"]) == {"mean", "p1", "p99"}
    assert {"median", "p99"} <= set(out["rotation_error_deg"]) and {"mean", "p99"} <= set(out["true_residual_px"])
    png = tmp_path / "fig3.png"
    proc = run_cli("simulate-calibration", "--trials", "2", "--sweep", "0:50:50", "--plot", png, "--mode", "fixed")
    assert proc.returncode == 0, proc.stderr
    img = cv2.imread(str(png))
    assert img is not None and img.shape[1] >= 800 and img.std() > 10
    assert "PP fixed" in proc.stdout
    bad = run_cli("simulate-calibration", "--trials", "0")
    assert bad.returncode == 2 and "--trials" in bad.stderr


def test_cli_subsample_pair_set_and_coverage_columns(run_cli):
    proc = run_cli("simulate-calibration", "--trials", "2", "--views", "array:5x3", "--pairs", "spanning", "--mode", "fixed",
                   "--json")
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    assert out["views"] == 15 and out["pairs"] == 3 * 9 + 5 * 3 and "3 x 5" in out["evaluation_set"]
    assert {"true_residual", "corner", "angle"} <= set(out["coverage"]) and "linear" in out
    text = run_cli("simulate-calibration", "--trials", "2", "--views", "default")
    assert text.returncode == 0 and "cov2σ" in text.stdout and "linear epipole" in text.stdout
    bad = run_cli("simulate-calibration", "--views", "array:5x1")
    assert bad.returncode == 2 and "--views" in bad.stderr


def test_the_default_views_beat_an_even_array_of_fewer_views_and_position_noise_sets_the_error():
    from lfstudio.calibration.pairs import DEFAULT_PAIR_SET, DEFAULT_VIEWS
    from lfstudio.calibration.simulate import SimulationConfig, simulate

    def rms(**kw):
        out = simulate(6, 0.0, 3, SimulationConfig(**kw), modes=("auto",))["with_principal_point"]
        return out["true_residual_px"]["rms"], out

    default, out = rms(views=DEFAULT_VIEWS, pair_set=DEFAULT_PAIR_SET)
    even, _ = rms(views="5x5", pair_set="all")
    exact_features, _ = rms(views=DEFAULT_VIEWS, pair_set=DEFAULT_PAIR_SET, feature_noise_px=0.0)
    exact_positions, _ = rms(views=DEFAULT_VIEWS, pair_set=DEFAULT_PAIR_SET, position_noise_um=0.0)
    assert default < 0.8 * even and default < 0.06
    assert abs(exact_features - default) < 0.15 * default      # the features are not the limit
    assert exact_positions < 0.25 * default                    # the rig's position noise is
    assert out["coverage"]["true_residual"][1] >= 0.85
