"""The position model on synthetic tracks: views are located from image shifts alone."""

from __future__ import annotations

import numpy as np
import pytest

from lfstudio.quality.positions import Observations, fit_tracks, position_errors, solve_positions


def _tracks(true_mm: np.ndarray, n_tracks: int, noise_px: float, seed: int = 0, f_px: float = 1400.0,
            views_per_track: int = 5) -> tuple[Observations, np.ndarray]:
    """Points at depths 1.5 … 5 m seen from ``true_mm`` (each track in a random handful of views)."""
    rng = np.random.default_rng(seed)
    n_views = len(true_mm)
    depth = rng.uniform(1.5, 5.0, n_tracks)
    s = f_px / (1000.0 * depth)
    a = rng.uniform(0, 1000, (n_tracks, 2))
    V, T, XY = [], [], []
    for t in range(n_tracks):
        for v in rng.choice(n_views, size=views_per_track, replace=False):
            V.append(v)
            T.append(t)
            XY.append(a[t] - s[t] * true_mm[v] + rng.normal(0, noise_px, 2))
    return Observations(np.array(V), np.array(T), np.array(XY), n_views, n_tracks), s


def _grid(cols: int = 4, rows: int = 3) -> np.ndarray:
    return np.array([(c * 4.0, r * 6.0) for r in range(rows) for c in range(cols)], float)


def test_noise_free_tracks_give_the_true_positions_and_depths():
    commanded = _grid()
    true = commanded.copy()
    true[5] += (0.9, -0.4)                 # one view stood elsewhere
    obs, s_true = _tracks(true, 600, noise_px=0.0)
    sol = solve_positions(obs, commanded, tolerance_mm=1e-7, iterations=30)
    error, w, scale = position_errors(commanded, sol.positions_mm)
    np.testing.assert_allclose(error[5], (0.9, -0.4), atol=1e-4)
    assert np.abs(np.delete(error, 5, axis=0)).max() < 1e-4
    assert w[5] == 0 and (np.delete(w, 5) > 0).all()           # the displaced view does not bend the fit
    tracks = fit_tracks(obs, sol.positions_mm / scale)
    # the gauge keeps the commanded scale, so depths come out in metres
    np.testing.assert_allclose(tracks.s_px_per_mm, s_true, rtol=1e-3)


def test_noisy_tracks_locate_views_to_micrometres_and_mismatches_are_ignored():
    commanded = _grid(5, 4)
    rng = np.random.default_rng(4)
    true = commanded + rng.normal(0, 0.08, commanded.shape)
    obs, _ = _tracks(true, 3000, noise_px=0.1, seed=1)
    bad = rng.choice(obs.count, obs.count // 20, replace=False)       # 5 % wild mismatches
    obs.xy[bad] += rng.normal(0, 15, (len(bad), 2))
    sol = solve_positions(obs, commanded)
    measured, _, _ = position_errors(commanded, sol.positions_mm)
    truth, _, _ = position_errors(commanded, true)
    assert np.sqrt(np.mean((measured - truth) ** 2)) < 0.02                   # mm, against 80 µm of scatter
    assert sol.sigma_px == pytest.approx(0.1 * np.sqrt(2) * 1.18, rel=0.35)    # robust scale of |residual|


def test_fixed_views_keep_their_positions():
    commanded = _grid()
    true = commanded.copy()
    true[0] += (0.5, 0.0)
    obs, _ = _tracks(true, 400, noise_px=0.0, seed=2)
    fixed = np.ones(len(commanded), bool)
    fixed[0] = False
    sol = solve_positions(obs, commanded, fixed=fixed, tolerance_mm=1e-7, iterations=30)
    np.testing.assert_allclose(sol.positions_mm[1:], commanded[1:])
    np.testing.assert_allclose(sol.positions_mm[0], true[0], atol=1e-3)


def test_views_without_tracks_are_not_located():
    obs = Observations(np.zeros(0, int), np.zeros(0, int), np.zeros((0, 2)), 3, 0)
    sol = solve_positions(obs, _grid(3, 1))
    assert not sol.observed.any()
    np.testing.assert_allclose(sol.positions_mm, _grid(3, 1))
