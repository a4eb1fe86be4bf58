"""Uncorrected lens distortion and sparse evidence: the stated uncertainty must still cover the truth.

Before: a 9 × 3 capture with ≈ 16 px of barrel distortion at the corners and no lens model gave ry
0.8° off at 4.4 σ without a word; ≈ 30 features per view gave 4–11° off, saved."""

import numpy as np
import pytest

from lfstudio.calibration.fit import CalibrationError, MIN_EVIDENCE_MATCHES, fit_rectification
from lfstudio.calibration.simulate import SimulationConfig, make_trial

WIDE_9x3 = dict(columns=9, rows=3, views="all", spacing_mm=(50.0, 50.0), points_per_pair=300)


def _fit(cfg, seed, **kw):
    trial = make_trial(np.random.default_rng(seed), 0.0, cfg, rotation_deg=[1.5, -2.5, 2.0])
    fit = fit_rectification(trial.matches, cfg.focal_length_px, cfg.image_size_px,
                            position_sigma_um=(cfg.position_noise_um,) * 2, **kw)
    return trial, fit


def test_uncorrected_barrel_distortion_is_named_fitted_and_covered():
    cfg = SimulationConfig(distortion_px=16.0, **WIDE_9x3)
    trial, fit = _fit(cfg, 3)
    radial = fit.extra["radial_distortion"]
    assert radial["applied"] and 13.0 < radial["corner_px"] < 19.0
    assert any("uncorrected lens distortion" in w and "barrel" in w for w in fit.extra["warnings"])
    z = np.abs(fit.rotation_deg - trial.rotation_deg) / fit.rotation_std_deg
    assert z.max() < 2.5, (fit.rotation_deg, fit.rotation_std_deg)
    # told the features are undistorted (a lens model was applied), it neither fits nor warns
    _, told = _fit(cfg, 3, radial_term="none")
    assert told.extra["radial_distortion"] is None and not told.extra["warnings"]


def test_no_distortion_no_warning():
    _, fit = _fit(SimulationConfig(**WIDE_9x3), 3)
    assert not fit.extra["radial_distortion"]["applied"] and not fit.extra["warnings"]


def test_too_little_evidence_is_refused_with_the_fix():
    cfg = SimulationConfig(columns=2, rows=1, views="all", points_per_pair=MIN_EVIDENCE_MATCHES - 6)
    with pytest.raises(CalibrationError, match="too little evidence.*in rows.*more texture.*more views"):
        _fit(cfg, 1)
