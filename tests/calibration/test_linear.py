import numpy as np
import pytest

from lfstudio.calibration.linear import linear_rotation
from lfstudio.calibration.model import rotation_angle_deg, rotation_matrix
from lfstudio.calibration.simulate import SimulationConfig, make_trial


@pytest.mark.parametrize("rot", [[0.4, -0.3, 0.2], [4.0, -5.0, 3.0]])
def test_exact_matches_give_the_exact_rotation_in_closed_form(rot):
    cfg = SimulationConfig(position_noise_um=0.0, feature_noise_px=0.0, points_per_pair=50)
    trial = make_trial(np.random.default_rng(0), 0.0, cfg, rotation_deg=rot)
    lin = linear_rotation(trial.matches, cfg.focal_length_px, cfg.image_size_px)
    assert rotation_angle_deg(rotation_matrix(lin.rotation_deg), rotation_matrix(rot)) < 1e-9
    assert lin.epipole_h @ rotation_matrix(rot) @ [1, 0, 0] > 0.999999


def test_noisy_matches_and_one_direction_only():
    cfg = SimulationConfig()
    trial = make_trial(np.random.default_rng(1), 0.0, cfg)
    lin = linear_rotation(trial.matches, cfg.focal_length_px, cfg.image_size_px)
    assert rotation_angle_deg(rotation_matrix(lin.rotation_deg), rotation_matrix(trial.rotation_deg)) < 0.1
    rows_only = [m for m in trial.matches if m.direction == "h"]
    assert linear_rotation(rows_only, cfg.focal_length_px, cfg.image_size_px) is None
