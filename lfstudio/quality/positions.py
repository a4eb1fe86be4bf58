"""Where each view really was taken, and how deep the scene is, from feature tracks alone.

Model (rectified images, see ``docs/conventions.md``): a scene point at depth Z seen from camera
position ``p`` (mm, on the acquisition plane) appears at ``o = a − s·p`` with ``s = f / (1000·Z)``
pixels per mm (``f`` the focal length in pixels of the working image) and ``a`` the point's image
position seen from the origin. A *track* is one point followed through several views; its ``a``
(2 numbers) and ``s`` (its depth) are unknown, and so is every view's true position. Solving all
tracks together (bilinear least squares, Gauss–Newton with the per-track unknowns eliminated by a
Schur complement, Huber-weighted against mismatched tracks) gives every view's position without
knowing the scene: a view that stood 1 mm to the right shifts every point by its own disparity for
1 mm, which no choice of depths can explain away. Only a global translation and scale (and, as
nothing in the images fixes them, the grid's overall rotation and shear) are free; a weak prior
pulls the solution to the commanded positions and :func:`robust_affine` then removes whatever
global affine map best explains the measured positions with the outlying views ignored.

Views in ``fixed`` keep their given positions (scan-time checks: the neighbours already judged).
Everything here is pure numpy/scipy; positions are mm, image coordinates are working-image pixels.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla


@dataclass
class Observations:
    """Feature tracks: observation ``j`` is track ``track[j]`` seen in view ``view[j]`` at ``xy[j]``
    (rectified working-image pixels). Views and tracks are numbered from 0."""

    view: np.ndarray      # (N,) int
    track: np.ndarray     # (N,) int
    xy: np.ndarray        # (N, 2) float
    n_views: int
    n_tracks: int

    @property
    def count(self) -> int:
        return int(len(self.view))


@dataclass
class PositionSolution:
    positions_mm: np.ndarray      # (n_views, 2) measured positions (gauge: weak prior to the given ones)
    sigma_px: float               # robust scale of the residuals
    observed: np.ndarray          # (n_views,) bool: the view takes part in at least one usable track
    iterations: int


@dataclass
class TrackFit:
    """Every track's image position and depth for given view positions, and the residuals."""

    a_px: np.ndarray              # (n_tracks, 2)
    s_px_per_mm: np.ndarray       # (n_tracks,) f / (1000 Z); NaN for a track that is not determined
    s_sigma: np.ndarray           # (n_tracks,) its standard error (for the given positions)
    residual_px: np.ndarray       # (N, 2) observation residual o − (a − s p)
    weight: np.ndarray            # (N,) robust weight (0: unused)
    views: np.ndarray             # (n_tracks,) how many views see each track


def _moments(T: np.ndarray, n: int, w: np.ndarray, p: np.ndarray) -> np.ndarray:
    """Per track 3 x 3 normal matrix of the unknowns (a_x, a_y, s) for positions ``p``."""
    U = np.zeros((n, 3, 3))
    U[:, 0, 0] = U[:, 1, 1] = np.bincount(T, w, n)
    U[:, 0, 2] = U[:, 2, 0] = -np.bincount(T, w * p[:, 0], n)
    U[:, 1, 2] = U[:, 2, 1] = -np.bincount(T, w * p[:, 1], n)
    U[:, 2, 2] = np.bincount(T, w * (p * p).sum(1), n)
    return U


def _track_fit(obs: Observations, P: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Closed-form (a, s) of every track for fixed positions; also whether it is determined."""
    T, n = obs.track, obs.n_tracks
    p = P[obs.view]
    M = _moments(T, n, w, p)
    rhs = np.stack([np.bincount(T, w * obs.xy[:, 0], n), np.bincount(T, w * obs.xy[:, 1], n),
                    -np.bincount(T, w * (p * obs.xy).sum(1), n)], 1)
    Sw, Spx, Spy, Spp = M[:, 0, 0], -M[:, 0, 2], -M[:, 1, 2], M[:, 2, 2]
    # determined: the track's views are not all at one position (weighted spread of p)
    spread = Spp - (Spx ** 2 + Spy ** 2) / np.maximum(Sw, 1e-12)
    ok = (Sw > 0) & (spread > 1e-9 * np.maximum(Spp, 1.0))
    sol = np.zeros((n, 3))
    if ok.any():
        sol[ok] = np.linalg.solve(M[ok], rhs[ok][..., None])[..., 0]
    return sol[:, :2], sol[:, 2], ok


def _huber(rn: np.ndarray, used: np.ndarray, k: float) -> tuple[np.ndarray, float]:
    sigma = max(1.4826 * float(np.median(rn[used])) if used.any() else 1.0, 1e-4)
    return np.where(used, np.minimum(1.0, k * sigma / np.maximum(rn, 1e-12)), 0.0), sigma


def solve_positions(obs: Observations, initial_mm: np.ndarray, *, fixed: np.ndarray | None = None,
                    prior_weight: float = 1e-6, iterations: int = 12, huber_k: float = 2.5,
                    tolerance_mm: float = 1e-3) -> PositionSolution:
    """Measured view positions from ``obs``; ``initial_mm`` are the commanded positions (start and
    weak prior). ``fixed``: views whose position is known and kept. Stops when a step changes the
    positions by less than ``tolerance_mm`` beyond a global affine map."""
    nV, nT, N = obs.n_views, obs.n_tracks, obs.count
    P0 = np.asarray(initial_mm, float).reshape(nV, 2)
    P = P0.copy()
    fixed = np.zeros(nV, bool) if fixed is None else np.asarray(fixed, bool)
    if N == 0 or nT == 0:
        return PositionSolution(P, float("nan"), fixed.copy(), 0)
    order = np.argsort(obs.track, kind="stable")
    V, T, XY = obs.view[order], obs.track[order], obs.xy[order]
    sobs = Observations(V, T, XY, nV, nT)
    starts = np.searchsorted(T, np.arange(nT))
    lengths = np.bincount(T, minlength=nT)
    max_len = int(lengths.max())
    # all (j, j') pairs of observations of one track
    pj = np.repeat(np.arange(N), max_len)
    pm = np.tile(np.arange(max_len), N)
    keep = pm < lengths[T[pj]]
    pj, pk = pj[keep], starts[T[pj[keep]]] + pm[keep]
    w = np.ones(N)
    sigma = 1.0
    a, s, ok = _track_fit(sobs, P, w)
    it = 0
    for it in range(1, iterations + 1):
        r = XY - a[T] + s[T][:, None] * P[V]
        w, sigma = _huber(np.hypot(r[:, 0], r[:, 1]), ok[T], huber_k)
        a, s, ok = _track_fit(sobs, P, w)
        w_eff = w * ok[T]
        r = XY - a[T] + s[T][:, None] * P[V]
        p = P[V]
        sT = s[T]
        # Gauss–Newton on (a, s, p); the per-track unknowns are eliminated (Schur complement)
        U = _moments(T, nT, w_eff, p) + np.eye(3) * 1e-9
        g_t = np.stack([-np.bincount(T, w_eff * r[:, 0], nT), -np.bincount(T, w_eff * r[:, 1], nT),
                        np.bincount(T, w_eff * (p * r).sum(1), nT)], 1)
        m = np.linalg.inv(U)[T]                                        # (N, 3, 3) per observation
        # X_j = U⁻¹ W_j with W_j = w s [[-1, 0], [0, -1], [px, py]]  → (N, 3, 2)
        ws = w_eff * sT
        X = np.empty((N, 3, 2))
        for i in range(3):
            X[:, i, 0] = (-m[:, i, 0] + m[:, i, 2] * p[:, 0]) * ws
            X[:, i, 1] = (-m[:, i, 1] + m[:, i, 2] * p[:, 1]) * ws
        # S = V − Σ_pairs W_jᵀ X_j'  with W_jᵀ X = ws_j (−X₀ + p·X₂) row by row
        Xk = X[pk]
        wsj = ws[pj][:, None]
        b0 = -wsj * (-Xk[:, 0, :] + p[pj, 0][:, None] * Xk[:, 2, :])
        b1 = -wsj * (-Xk[:, 1, :] + p[pj, 1][:, None] * Xk[:, 2, :])
        vd = np.bincount(V, w_eff * sT * sT, nV) + prior_weight
        g_p = np.stack([np.bincount(V, ws * r[:, 0], nV), np.bincount(V, ws * r[:, 1], nV)], 1)
        g_p += prior_weight * (P - P0)
        Xg = np.einsum("jac,ja->jc", X, g_t[T])                          # W_jᵀ U⁻¹ g_t
        rhs = -g_p + np.stack([np.bincount(V, Xg[:, 0], nV), np.bincount(V, Xg[:, 1], nV)], 1)
        n2 = 2 * nV
        r0, c0 = 2 * V[pj], 2 * V[pk]
        flat = np.concatenate([r0 * n2 + c0, r0 * n2 + c0 + 1, (r0 + 1) * n2 + c0, (r0 + 1) * n2 + c0 + 1])
        vals = np.concatenate([b0[:, 0], b0[:, 1], b1[:, 0], b1[:, 1]])
        free = np.repeat(~fixed, 2)
        dp = np.zeros(n2)
        if n2 <= 2400:
            S = np.bincount(flat, vals, n2 * n2).reshape(n2, n2)
            S[np.arange(n2), np.arange(n2)] += np.repeat(vd, 2)
            Sf = S[free][:, free]
            if free.any():
                damp = 1e-9 * max(float(np.abs(np.diag(Sf)).max()), 1.0)
                dp[free] = np.linalg.solve(Sf + np.eye(Sf.shape[0]) * damp, rhs.ravel()[free])
        else:
            S = sp.coo_matrix((np.concatenate([vals, np.repeat(vd, 2)]),
                               (np.concatenate([flat // n2, np.arange(n2)]),
                                np.concatenate([flat % n2, np.arange(n2)]))), shape=(n2, n2)).tocsc()
            Sf = S[free][:, free]
            if free.any():
                damp = 1e-9 * max(float(np.abs(Sf.diagonal()).max()), 1.0)
                dp[free] = np.asarray(spla.spsolve(Sf + sp.identity(Sf.shape[0], format="csc") * damp, rhs.ravel()[free]))
        dP = dp.reshape(nV, 2)
        P = P + dP
        a, s, ok = _track_fit(sobs, P, w)
        # converged when the step, apart from a global affine change (free anyway), is tiny
        X_aff = np.column_stack([P, np.ones(nV)])
        coef, *_ = np.linalg.lstsq(X_aff, dP, rcond=None)
        if np.abs(dP - X_aff @ coef).max() < tolerance_mm:
            break
    observed = np.bincount(V, (w * ok[T]) > 0, nV) > 0
    return PositionSolution(P, sigma, observed | fixed, it)


def fit_tracks(obs: Observations, positions_mm: np.ndarray, sigma_px: float = 1.0, huber_k: float = 2.5) -> TrackFit:
    """Every track of ``obs`` for the given positions (Huber-weighted; ``sigma_px`` starts the robust scale)."""
    nT, N = obs.n_tracks, obs.count
    P = np.asarray(positions_mm, float)
    if N == 0:
        return TrackFit(np.zeros((nT, 2)), np.full(nT, np.nan), np.full(nT, np.nan), np.zeros((0, 2)), np.zeros(0),
                        np.zeros(nT, int))
    a, s, ok = _track_fit(obs, P, np.ones(N))
    sigma = sigma_px
    for _ in range(3):
        r = obs.xy - a[obs.track] + s[obs.track][:, None] * P[obs.view]
        w, sigma = _huber(np.hypot(r[:, 0], r[:, 1]), ok[obs.track], huber_k)
        a, s, ok = _track_fit(obs, P, w)
    r = obs.xy - a[obs.track] + s[obs.track][:, None] * P[obs.view]
    w_eff = w * ok[obs.track]
    s_sigma = np.full(nT, np.nan)
    if ok.any():
        U = _moments(obs.track, nT, w_eff, P[obs.view])[ok] + np.eye(3) * 1e-12
        s_sigma[ok] = sigma * np.sqrt(np.abs(np.linalg.inv(U)[:, 2, 2]))
    return TrackFit(a, np.where(ok, s, np.nan), s_sigma, r, w_eff, np.bincount(obs.track, minlength=nT))


def _rot90(v: np.ndarray) -> np.ndarray:
    return np.array([-v[1], v[0]])


def robust_affine(source_mm: np.ndarray, target_mm: np.ndarray, *, floor_mm: float = 0.01,
                  use: np.ndarray | None = None, iterations: int = 20) -> tuple[np.ndarray, np.ndarray]:
    """The 2-D affine map A (2 x 3) with ``target ≈ A · [source, 1]`` fitted with Tukey weights, so
    that a few far-off points (displaced views) do not bend it; also the final weights (0 = outlier).

    Sources on one line (a single row or column of views) get the affine map along the line and a
    similarity across it; with too few points, a translation.
    """
    src = np.asarray(source_mm, float)
    dst = np.asarray(target_mm, float)
    n = len(src)
    use = np.ones(n, bool) if use is None else np.asarray(use, bool)
    A = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])
    if use.sum() == 0:
        return A, np.zeros(n)
    A[:, 2] = np.median(dst[use] - src[use], axis=0)
    mean = src[use].mean(axis=0)
    centred = src - mean
    _, sv, vt = np.linalg.svd(centred[use], full_matrices=False) if use.sum() > 1 else (None, np.zeros(2), np.eye(2))
    rank = int(np.count_nonzero(sv > 1e-6 * max(float(sv.max(initial=0.0)), 1e-9)))
    u = vt[0]
    w = use.astype(float)
    for _ in range(iterations):
        res = dst - src @ A[:, :2].T - A[:, 2]
        rn = np.hypot(res[:, 0], res[:, 1])
        scale = max(1.4826 * float(np.median(rn[use])), floor_mm)
        c = 4.685 * scale
        w = np.where(use & (rn < c), (1 - (rn / c) ** 2) ** 2, 0.0)
        sw = np.sqrt(w)[:, None]
        if rank >= 2 and (w > 0).sum() >= 4:
            B, *_ = np.linalg.lstsq(np.column_stack([centred, np.ones(n)]) * sw, dst * sw, rcond=None)
            lin, offset = B[:2].T, B[2]
        elif rank == 1 and (w > 0).sum() >= 3:
            along = centred @ u
            B, *_ = np.linalg.lstsq(np.column_stack([along, np.ones(n)]) * sw, dst * sw, rcond=None)
            p, offset = B[0], B[1]
            lin = np.outer(p, u) + np.outer(_rot90(p), _rot90(u))
        else:
            t = np.average(dst - src, axis=0, weights=np.maximum(w, 1e-12)) if w.sum() > 0 else A[:, 2]
            A = np.array([[1.0, 0.0, t[0]], [0.0, 1.0, t[1]]])
            continue
        A_new = np.column_stack([lin, offset - lin @ mean])
        done = np.abs(A_new - A).max() < 1e-9
        A = A_new
        if done:
            break
    return A, w


def position_errors(commanded_mm: np.ndarray, measured_mm: np.ndarray, use: np.ndarray | None = None
                    ) -> tuple[np.ndarray, np.ndarray, float]:
    """Each view's error in the commanded frame — measured position mapped back through the robust
    affine fit (:func:`robust_affine`) minus the commanded one —, the fit's weights (0: outlier) and
    its scale (divide the measured positions by it to give track depths the commanded scale)."""
    c = np.asarray(commanded_mm, float)
    A, w = robust_affine(c, measured_mm, use=use)
    back = np.linalg.solve(A[:, :2], (np.asarray(measured_mm, float) - A[:, 2]).T).T
    return back - c, w, float(np.sqrt(abs(np.linalg.det(A[:, :2]))))
