"""Where a view's neighbours really stood, measured from the images: each neighbour's offset from
the reference (in horizontal spacings, as :class:`lfstudio.depth.dense.Neighbour` takes it).

The sweep samples a neighbour at ``(u − d·dx, v − d·dy)``; an offset wrong by the rig's
repeatability (80 µm of a 4 mm spacing: 2 %) makes every neighbour disagree a little with the others
about the same disparity, which blurs the cost's minimum. In rectified views a feature ``i`` of the
reference seen in neighbour ``n`` moved by ``x_ref − x_n = D_i · o_n`` (``D_i`` its disparity per
horizontal spacing, ``o_n`` the neighbour's offset): a rank-one model over the SIFT matches of the
reference with each neighbour, solved by alternating least squares with the outliers dropped. Its
scale is free (near scene and long baselines look alike): it is pinned to the offsets the rig gives
(grid or recorded positions) in the least-squares sense, allowing a common shift (the reference's
own position error moves all its offsets alike).

Each measured offset is then combined with the rig's (its prior): the rig's repeatability
(``rig.repeatability_um`` of the manifest, else the reference gantry's 80 × 50 µm; √2 of it for the
offset of two views) against the measurement's own standard error, weighted by their inverse
variances. Where the repeatability is negligible against a spacing (:func:`worth_measuring`), or the
positions are exact (an HCI folder: views rendered where its format states), nothing is measured
and the rig's offsets are used as they are.

Virtual studio, 9 × 3 at 1000 px (rig noise 80 × 50 µm): the offsets' error against the truth falls
from 0.020 to 0.004 spacings RMS; what is left of the depth error is mostly each view's scale, which
only the rig's positions fix (their noise averaged over the neighbours: ≈ 0.2 %).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import cv2
import numpy as np

#: measure only where the rig's repeatability (of a relative offset, in spacings) exceeds this: a
#: measurement's own error is about 0.003–0.005 spacings
MEASURE_ABOVE_SPACINGS = 0.002
#: matches: Lowe's ratio; the displacement must run along the expected offset within this (px)
RATIO = 0.8
ACROSS_PX = 2.0
#: a neighbour with fewer matches than this (after outliers) keeps the rig's offset, as does one
#: whose measured offset lies more than OUTLIER_SIGMAS of the rig's repeatability from the rig's
MIN_MATCHES = 8
OUTLIER_SIGMAS = 5.0
ITERATIONS = 12


@dataclass
class MeasuredOffsets:
    offsets: np.ndarray          # (n, 2) spacings: the combined estimate (the rig's where not measured)
    measured: np.ndarray         # (n,) bool: a measurement went into it
    sigma: np.ndarray            # (n, 2) the measurement's standard error (inf where not measured)
    matches: int                 # matches used, all neighbours
    residual_px: float           # median residual of the model (px)

    def describe(self, prior: np.ndarray) -> dict:
        change = np.linalg.norm(self.offsets - prior, axis=1)
        return {"measured": int(self.measured.sum()), "of": int(len(self.measured)), "matches": int(self.matches),
                "residual_px": round(float(self.residual_px), 4),
                "change_rms_spacings": round(float(np.sqrt(np.mean(change ** 2))) if len(change) else 0.0, 5)}


def worth_measuring(prior_sigma: Sequence[float]) -> bool:
    """Whether the rig's offsets are uncertain enough (``prior_sigma``: x, y in spacings) to measure."""
    return max(float(v) for v in prior_sigma) > MEASURE_ABOVE_SPACINGS


def prior_sigma_spacings(repeatability_um: Sequence[float], spacing_x_mm: float) -> tuple[float, float]:
    """The standard deviation of two views' relative offset (x, y), in horizontal spacings, from the
    rig's repeatability of one position (µm)."""
    s = np.sqrt(2.0) / 1000.0 / max(float(spacing_x_mm), 1e-12)
    return float(repeatability_um[0]) * s, float(repeatability_um[1]) * s


def measure_offsets(ref_xy: np.ndarray, ref_desc: np.ndarray, neighbours: Sequence[tuple[np.ndarray, np.ndarray]],
                    prior: np.ndarray, prior_sigma: Sequence[float]) -> MeasuredOffsets:
    """Each neighbour's offset from the reference (module docstring). ``ref_xy`` (N, 2) rectified
    pixels and ``ref_desc`` (N, 128) SIFT descriptors of the reference; ``neighbours``: (xy, desc)
    of each; ``prior`` (n, 2): the rig's offsets (spacings); ``prior_sigma``: their standard
    deviation (x, y)."""
    prior = np.asarray(prior, float).reshape(-1, 2)
    n_nb = len(neighbours)
    sig_p = np.array([max(float(v), 1e-12) for v in prior_sigma])
    unmeasured = MeasuredOffsets(prior.copy(), np.zeros(n_nb, bool), np.full((n_nb, 2), np.inf), 0, float("nan"))
    if len(ref_xy) < MIN_MATCHES or n_nb < 2:
        return unmeasured
    bf = cv2.BFMatcher(cv2.NORM_L2)
    nidx_l, iidx_l, delta_l = [], [], []
    for n, (xy, desc) in enumerate(neighbours):
        g = prior[n]
        if len(xy) < 2 or not np.any(g):
            continue
        pairs = bf.knnMatch(np.asarray(ref_desc, np.float32), np.asarray(desc, np.float32), k=2)
        ij = np.array([(p[0].queryIdx, p[0].trainIdx) for p in pairs
                       if len(p) == 2 and p[0].distance < RATIO * p[1].distance], int).reshape(-1, 2)
        if not len(ij):
            continue
        d = np.asarray(ref_xy, float)[ij[:, 0]] - np.asarray(xy, float)[ij[:, 1]]
        u = g / np.linalg.norm(g)
        ok = (d @ u > 0) & (np.abs(d @ np.array([-u[1], u[0]])) < ACROSS_PX)
        nidx_l.append(np.full(int(ok.sum()), n))
        iidx_l.append(ij[ok, 0])
        delta_l.append(d[ok])
    if not nidx_l:
        return unmeasured
    nidx, iidx, delta = np.concatenate(nidx_l), np.concatenate(iidx_l), np.concatenate(delta_l)
    n_feat = len(ref_xy)
    keep = np.ones(len(nidx), bool)
    o = prior.copy()
    disp = np.zeros(n_feat)
    res = np.zeros(len(nidx))
    for it in range(ITERATIONS):
        num, den, cnt = np.zeros(n_feat), np.zeros(n_feat), np.zeros(n_feat)
        np.add.at(num, iidx[keep], (delta[keep] * o[nidx[keep]]).sum(1))
        np.add.at(den, iidx[keep], (o[nidx[keep]] ** 2).sum(1))
        np.add.at(cnt, iidx[keep], 1)
        disp = np.where(den > 0, num / np.maximum(den, 1e-12), 0.0)
        use = keep & (cnt[iidx] >= 2)             # a feature seen by one neighbour fixes no offset
        for n in range(n_nb):
            s = use & (nidx == n)
            if s.sum() >= MIN_MATCHES:
                dn = disp[iidx[s]]
                o[n] = (dn[:, None] * delta[s]).sum(0) / max(float((dn ** 2).sum()), 1e-12)
        res = np.linalg.norm(delta - disp[iidx][:, None] * o[nidx], axis=1)
        if it >= 3:
            keep = res < max(3.0 * 1.4826 * float(np.median(res[keep])), 0.05)
    use = keep & (np.bincount(iidx[keep], minlength=n_feat)[iidx] >= 2)
    counts = np.bincount(nidx[use], minlength=n_nb)
    measured = counts >= MIN_MATCHES
    if measured.sum() < 2:
        return unmeasured
    # the scale is free: pinned to the rig's offsets (least squares over the measured neighbours,
    # with a shift: the reference's own position error moves every offset alike, which on a
    # one-sided neighbourhood would otherwise pass for a scale)
    # a neighbour whose measurement disagrees with the rig's offset beyond OUTLIER_SIGMAS of the
    # rig's repeatability (after the scale and the common shift) was matched wrongly (a repeated
    # texture, few features): it keeps the rig's offset and pins nothing
    scale = 1.0
    for _ in range(3):
        if measured.sum() < 2:
            return unmeasured
        om, pm = o[measured], prior[measured]
        oc, pc = om - om.mean(axis=0), pm - pm.mean(axis=0)
        scale = float((pc * oc).sum() / max(float((oc ** 2).sum()), 1e-12))
        shift = (pm - scale * om).mean(axis=0)
        off = np.abs(scale * o + shift - prior) / sig_p[None, :]
        agree = measured & (off.max(axis=1) <= OUTLIER_SIGMAS)
        if np.array_equal(agree, measured):
            break
        measured = agree
    o = o * scale
    sigma_res = 1.4826 * float(np.median(res[use])) / np.sqrt(2.0)      # per component, px
    sigma = np.full((n_nb, 2), np.inf)
    for n in np.nonzero(measured)[0]:
        dn = disp[iidx[use & (nidx == n)]] * scale
        sigma[n] = sigma_res / np.sqrt(max(float((dn ** 2).sum()), 1e-12))
    w_m = np.where(measured[:, None], 1.0 / np.maximum(sigma, 1e-12) ** 2, 0.0)
    w_p = 1.0 / sig_p[None, :] ** 2
    combined = (prior * w_p + np.where(measured[:, None], o, 0.0) * w_m) / (w_p + w_m)
    return MeasuredOffsets(combined, measured, sigma, int(use.sum()), float(np.median(res[use])))
