r"""Noise levels of the measurements and the smoothing of the indenter record.

The noise-aware objective (`objective.Objective` with a `NoiseModel`) is a Gaussian
likelihood: each residual is divided by the standard deviation of its measurement, so that
Phi = sum r^2 is -2 log L up to a constant and the volumetric and indenter terms balance by
information rather than by units.

* Indenter: white sensor noise on the depth and force samples (the seed paper's system:
  3.9 um and 13 mN RMS with its controller, section 2.1.1). The levels come from the bundle
  (`displacement_noise_rms_m`, `force_noise_rms_N`) and, where those are 0, from the record
  itself (`white_noise_rms`: second differences of the samples, robust to the kinks of the
  load reversal).
* Tracking: the frame-pair motion u_OF has an error that grows where the texture (the
  confidence c_OF) is weak and with speckle decorrelation. Its level is estimated from the
  flow itself (`tracking_noise`): true tissue motion is smooth in time at the frame rate,
  so the second difference of u_OF over frame pairs is noise (robustly, at confident nodes).
  Its dependence on c is taken as sigma(c) = sigma_1 c^-1/2, i.e. the paper's weights c: on
  the issue-11 informative case (warped volumes, error against the known motion) the error
  times sqrt(c) ranges 0.6-2.5 um over confidence bins, so that law holds within about a
  factor 2. A floor stands for the tracker's systematic error on noise-free images, which
  differences in time cannot see (its frame-to-frame correlation there is 0.97).
"""

from __future__ import annotations

import functools
import hashlib
import json
import logging
from collections import OrderedDict
from dataclasses import asdict, dataclass

import numpy as np

__all__ = ["NoiseModel", "white_noise_rms", "reversals", "kinks", "smooth_record", "piecewise_quadratic",
           "tracking_noise", "noise_model"]

log = logging.getLogger(__name__)

_MAD = 1.482602218505602   # MAD -> standard deviation of a normal distribution

# The tracker's floor: a frame-pair motion error of this fraction of the finest voxel even on
# noise-free warped images (interpolation and window effects: 0.015 voxel RMS at a reversal
# on the default refinement, tests/test_imaging_tracking.py; 1.3 um = 0.0043 voxel
# c-weighted RMS on the issue-11 informative case, so the floor of 6 um is 4.6x that)
TRACKING_FLOOR_VOXEL = 0.02

# The force's floor: the record is not compared more closely than the model can match it. The
# model's own error in the force (its mesh: the coarse benchmark mesh is 4.6 % stiffer at the
# rim than the fine one; its law) is systematic and smooth, and a score test sees it as an
# effect when the force's level is far below it. On the warped elastic null of seed 38 with
# `synthesize`'s noise-free record, the floor of 1e-4 of the range (35 uN; 0.2 mN after the
# balance stage) let a 0.1 mN RMS misfit of the force add a sphere, a sliding bottom and the
# quartic bulk term. 1 % of the range (3.5 mN on a 6 mm test, a quarter of the paper's 13 mN
# sensor noise) stands for it. A noise-free depth record drives the model: its floor (1e-4 of
# the range) only keeps the likelihood finite.
FORCE_MODEL_ERROR = 0.01
DEPTH_FLOOR = 1e-4


@dataclass
class NoiseModel:
    """Standard deviations of the measurements (SI). `sources` says where each came from."""
    force_N: float
    depth_m: float
    tracking_m: float          # frame-pair motion error at confidence 1
    sources: dict

    def to_json(self) -> str:
        return json.dumps(asdict(self))


def white_noise_rms(y) -> float:
    """RMS of white noise on a smooth, uniformly sampled record: the second difference of
    white noise of RMS s has RMS sqrt(6) s, a smooth signal adds only y'' dt^2, and the median
    absolute deviation ignores the few samples at a kink (the load reversal)."""
    d2 = np.diff(np.asarray(y, float), 2)
    if d2.size < 8:
        raise ValueError("too few samples to estimate the noise level (need at least 10)")
    return float(_MAD * np.median(np.abs(d2 - np.median(d2))) / np.sqrt(6.0))


def reversals(t, y, sigma, min_fraction=0.05):
    """Times where a load history turns (local extrema of the GCV-smoothed record that
    stand out of it by `min_fraction` of its range): the kinks a spline must not round."""
    from scipy.signal import find_peaks

    t, y = np.asarray(t, float), np.asarray(y, float)
    if sigma <= 0 or len(t) < 10:
        ys = y
    else:
        ys = _gcv_spline(t, y)(t)
    prom = min_fraction * float(np.ptp(ys))
    if prom <= 0:
        return np.zeros(0)
    peaks = np.concatenate([find_peaks(ys, prominence=prom)[0], find_peaks(-ys, prominence=prom)[0]])
    return np.sort(t[peaks])


def _per_record(fn):
    """Remember fn's last 16 results by the bytes of its array arguments. A fit builds several
    objectives on one indenter record (the merged-pair search, the tracker response, each
    discovery step), and each GCV spline costs 0.3-1 s (`SPLINE_BINS`)."""
    cache = OrderedDict()

    def key(a):
        if isinstance(a, np.ndarray) or isinstance(a, (list, tuple)):
            a = np.ascontiguousarray(a, dtype=float)
            return (a.shape, hashlib.sha1(a.tobytes()).hexdigest())
        return a

    @functools.wraps(fn)
    def wrapper(*args, **kwargs):
        k = (tuple(key(a) for a in args), tuple(sorted((n, key(v)) for n, v in kwargs.items())))
        if k not in cache:
            cache[k] = fn(*args, **kwargs)
            if len(cache) > 16:
                cache.popitem(last=False)
        out = cache[k]
        return out.copy() if isinstance(out, np.ndarray) else out
    return wrapper


def _window_slopes(t, y, n):
    """Least-squares slopes of y(t) over the n + 1 samples ending at (left) and starting at
    (right) each sample i = n .. len - n - 1, and their standard errors per unit noise."""
    c = lambda a: np.concatenate([[0.0], np.cumsum(a)])
    tc = t - t.mean()
    St, Sy, Stt, Sty = c(tc), c(y), c(tc * tc), c(tc * y)
    m = n + 1

    def fit(lo):   # windows [lo, lo + n]
        hi = lo + m
        st, sy, stt, sty = St[hi] - St[lo], Sy[hi] - Sy[lo], Stt[hi] - Stt[lo], Sty[hi] - Sty[lo]
        sxx = stt - st * st / m
        return (sty - st * sy / m) / sxx, 1.0 / np.sqrt(sxx)

    i = np.arange(n, len(t) - n)
    (bl, el), (br, er) = fit(i - n), fit(i)
    return i, bl, br, np.hypot(el, er)


@_per_record
def kinks(t, y, sigma, min_fraction=0.05, window=None, z=6.0):
    """Times where a load history's slope changes abruptly (a reversal, the start or end of a
    hold, a change of rate): the breaks a smoothing spline must not round, with the
    `reversals` (which also catch smooth turns).

    A sample is a candidate where the slopes fitted over the `window` samples on either side
    differ by more than z of their standard errors (noise `sigma`) and by more than
    `min_fraction` of the record's largest slope, and by the most within a window. The window
    (by default) is as wide as makes the noise's threshold half the rate's: 37 samples for a
    2 mm/s ramp at 100 Hz with 3.9 um noise, 0.8 s for a 0.2 mm/s ramp at 1 kHz. Its time is
    refined between samples by the continuous hinge (two lines meeting at the kink) that
    fits the 2 `window` + 1 samples best, and it is kept where that hinge beats a quadratic
    by z^2 sigma^2 in squared residual (a smooth turn is no kink). Measured on a 6 mm ramp,
    2 s hold and unload at 100 Hz with the paper's 3.9 um noise (tests/test_noise.py): the
    hold's start and end within 0.01 s, and the drive depth of the frames within 1 um of
    the truth instead of 17 um with the reversals alone. A reversal of the record away from
    the kinks is kept where the slopes on its two sides have opposite signs and are steep (a
    smooth turn); the noise's extremum on a hold is not."""
    t, y = np.asarray(t, float), np.asarray(y, float)
    turns = reversals(t, y, sigma, min_fraction)
    if sigma <= 0 or len(t) < 40:
        return turns
    dt = float(np.median(np.diff(t)))
    if window is None:
        # wide enough that the noise's threshold is half the rate's (z sigma sqrt(2) /
        # (dt sqrt(m (m^2 - 1) / 12)) = steep / 2 for m = n + 1 samples a side), the
        # steepest slope taken over windows of a fiftieth of the record
        _, bl, br, _ = _window_slopes(t, y, max(4, len(t) // 50))
        steep = min_fraction * max(np.abs(bl).max(), np.abs(br).max())
        m = (12.0 * (2.0 * np.sqrt(2.0) * z * sigma / (dt * steep)) ** 2) ** (1 / 3) if steep > 0 else 5
        window = int(np.clip(np.ceil(m), 5, len(t) // 8))
    i, bl, br, se = _window_slopes(t, y, window)
    jump = np.abs(br - bl)
    steep = min_fraction * max(np.abs(bl).max(), np.abs(br).max())
    cand = np.flatnonzero((jump > z * sigma * se) & (jump > steep))
    found = []
    for k in cand[np.argsort(-jump[cand])]:
        c = i[k]
        if any(abs(c - f) <= window for f, _ in found):
            continue
        s = slice(c - window, c + window + 1)
        ts, ys = t[s], y[s]
        quad = np.linalg.lstsq(np.vander(ts - t[c], 3), ys, rcond=None)[1]
        best = (np.inf, t[c])
        for tk in np.linspace(t[c - 2], t[c + 2], 81):
            A = np.column_stack([np.ones_like(ts), ts - tk, np.maximum(ts - tk, 0.0)])
            r = ys - A @ np.linalg.lstsq(A, ys, rcond=None)[0]
            best = min(best, (float(r @ r), float(tk)))
        if quad.size and quad[0] - best[0] > (z * sigma) ** 2:
            found.append((c, best[1]))
    out = [tk for _, tk in found]
    # a reversal away from the kinks is kept where the record turns (slopes of opposite sign,
    # each steeper than min_fraction of the largest): not the noise's extremum on a hold
    for tr in turns:
        c = int(np.clip(np.searchsorted(t, tr), window, len(t) - window - 1)) - window
        if all(abs(tr - tk) > window * dt for tk in out) and bl[c] * br[c] < 0 \
                and min(abs(bl[c]), abs(br[c])) > steep:
            out.append(float(tr))
    return np.sort(np.asarray(out, float))


#: a piece of a record with more samples is smoothed from the means of at most this many bins of
#: consecutive samples, weighted by their counts (`_binned`)
SPLINE_BINS = 1000


def _binned(t, y, bins: int | None = None):
    """(t, y, w) for `make_smoothing_spline`: the samples themselves (w None) up to `bins` of
    them, else the means of `bins` runs of consecutive samples and their counts as weights.
    The weighted spline of the means has the same data term, up to a constant, for a curve
    straight within a bin, so GCV picks the same smoothing; scipy's GCV is a Python loop over
    the samples (4.8 s for 8000). On a curved 4 s ramp with 3.9 um noise (three seeds) the error
    against the planted curve was the same to 3 digits (RMS 0.054-0.062 sigma at 8000 samples,
    0.100-0.106 at 2000), in 0.3-0.5 s instead of 2.9-4.0 s (`tests/test_noise.py`,
    `test_a_long_record_is_smoothed_from_its_bin_means`)."""
    n, bins = len(t), SPLINE_BINS if bins is None else int(bins)
    if n <= bins:
        return t, y, None
    edges = np.linspace(0, n, bins + 1).astype(int)
    count = np.diff(edges).astype(float)
    return (np.add.reduceat(t, edges[:-1]) / count, np.add.reduceat(y, edges[:-1]) / count, count)


def _gcv_spline(t, y):
    """scipy's `make_smoothing_spline` of y(t), lam by GCV, from the bin means of a long record."""
    from scipy.interpolate import make_smoothing_spline
    return make_smoothing_spline(*_binned(t, y))


@_per_record
def smooth_record(t, y, sigma, breaks=()):
    """Smoothing spline of noisy samples y(t) (scipy's `make_smoothing_spline`, lam by
    generalized cross-validation), one per piece between the `breaks` (the load history's
    kinks, which a single spline would round); `sigma` <= 0 (a noise-free record) gives the linear
    interpolant of the samples. Returns a callable.

    GCV rather than the discrepancy principle (residual RMS = sigma): on a 6 mm load-unload
    depth at 100 Hz with 3.9 um noise (three seeds), one spline over the reversal leaves
    0.47 sigma RMS error with GCV and 4-6 sigma at the kink, 0.52-0.60 and 7-9 sigma with the
    discrepancy principle; split at the reversal, GCV leaves 0.07-0.11 sigma RMS and at most
    0.28 sigma (tests/test_noise.py). A piece of more than `SPLINE_BINS` samples is smoothed
    from its bin means (`_binned`)."""

    t, y = np.asarray(t, float), np.asarray(y, float)
    if sigma <= 0:
        return lambda tq: np.interp(tq, t, y)
    edges = np.concatenate([[t[0]], np.asarray(breaks, float), [t[-1]]])
    pieces = []
    for a, b in zip(edges[:-1], edges[1:]):
        m = (t >= a - 1e-12) & (t <= b + 1e-12)
        pieces.append(_gcv_spline(t[m], y[m]) if m.sum() >= 5 else
                      (lambda tq, tm=t[m], ym=y[m]: np.interp(tq, tm, ym)))

    def smoothed(tq):
        tq = np.asarray(tq, float)
        k = np.clip(np.searchsorted(edges, tq, side="right") - 1, 0, len(pieces) - 1)
        out = np.empty(tq.shape)
        for i, piece in enumerate(pieces):
            out[k == i] = piece(tq[k == i])
        return out
    return smoothed


def piecewise_quadratic(t_nodes, t_query, breaks=()):
    """Sparse matrix W (len(t_query) x len(t_nodes)) of quadratic Lagrange interpolation of
    values at `t_nodes` (increasing) at `t_query`, through three neighbouring nodes that do
    not straddle a break (linear where a piece has two nodes). Linear interpolation of the
    modelled force between frames misses F'' dt^2 / 8, 1 mN for a 0.25 s frame interval,
    which over hundreds of samples with 13 mN noise is a 2-sigma bias."""
    import scipy.sparse as sp

    tn, tq = np.asarray(t_nodes, float), np.asarray(t_query, float)
    tol = 1e-9 * max(1.0, abs(tn[-1]))
    edges = np.concatenate([[-np.inf], np.asarray(breaks, float), [np.inf]])
    piece_q = np.clip(np.searchsorted(edges, tq, side="right") - 1, 0, len(edges) - 2)
    rows, cols, vals = [], [], []
    k = np.clip(np.searchsorted(tn, tq) - 1, 0, len(tn) - 2)
    for i, (tqi, ki, pq) in enumerate(zip(tq, k, piece_q)):
        lo, hi = edges[pq] - tol, edges[pq + 1] + tol     # a node on a break serves both sides
        cand = [j for j in (ki - 1, ki, ki + 1, ki + 2) if 0 <= j < len(tn) and lo <= tn[j] <= hi]
        if len(cand) < 2:
            cand = [ki, ki + 1]
        if len(cand) > 3:   # the three nearest
            cand = sorted(cand, key=lambda j: abs(tn[j] - tqi))[:3]
        cand = sorted(cand)
        for j in cand:
            w = 1.0
            for m in cand:
                if m != j:
                    w *= (tqi - tn[m]) / (tn[j] - tn[m])
            rows.append(i)
            cols.append(j)
            vals.append(w)
    return sp.csr_matrix((vals, (rows, cols)), shape=(len(tq), len(tn)))


def tracking_noise(u_of, c_of, dt, grid_spacing_m=None, confidence_floor=0.1) -> tuple[float, str]:
    """Frame-pair tracking error at confidence 1 (m), from the flow itself.

    The motion per unit time of a node changes smoothly from one frame pair to the next, so
    e_k = (u_k / dt_k - (u_{k-1} / dt_{k-1} + u_{k+1} / dt_{k+1}) / 2) dt_k is noise of variance
    1.5 sigma_k^2 (independent pairs); sigma_k^2 c_k is constant under the weights c. Robust
    (median absolute deviation of e sqrt(c) at nodes with c >= `confidence_floor`). Floored at
    `TRACKING_FLOOR_VOXEL` of the finest voxel spacing when given."""
    u_of, c_of = np.asarray(u_of, float), np.asarray(c_of, float)
    dt = np.asarray(dt, float)
    source = "estimated from the flow (second differences over frame pairs)"
    if u_of.shape[0] < 3:
        est = 0.0
    else:
        v = u_of / dt[:, None, None]
        e = (v[1:-1] - 0.5 * (v[:-2] + v[2:])) * dt[1:-1, None, None]
        c = c_of[1:-1]
        ok = c >= confidence_floor
        est = float(_MAD * np.median(np.abs(e[ok] * np.sqrt(c[ok]))) / np.sqrt(1.5)) if ok.any() else 0.0
    if grid_spacing_m is not None:
        floor = TRACKING_FLOOR_VOXEL * float(np.min(grid_spacing_m))
        if est < floor:
            return floor, f"floor {TRACKING_FLOOR_VOXEL:g} voxel (estimate from the flow {est:.3g} m)"
    return est, source


def noise_model(indenter, flow, force_N=None, depth_m=None, tracking_m=None) -> NoiseModel:
    """Noise levels for a bundle's indenter record and a flow: given values first, then the
    bundle's, then estimates from the record itself. The force's level is at least
    `FORCE_MODEL_ERROR` of its range (the model's own error) unless given; a noise-free depth
    record (synthetic data) gets `DEPTH_FLOOR` of its range, so that the likelihood stays finite."""
    sources = {}

    def level(given, recorded, samples, name, unit, floor_fraction):
        if given is not None:
            sources[name] = "given"
            return float(given)
        floor = floor_fraction * float(np.ptp(samples))
        if recorded and recorded > 0:
            value, source = float(recorded), "bundle"
        else:
            value, source = white_noise_rms(samples), "estimated from the record (second differences)"
        if value < floor:
            sources[name] = f"floor {floor_fraction:g} of the range ({source}: {value:.3g} {unit})"
            return floor
        sources[name] = source
        return value

    f = level(force_N, indenter.force_noise_rms_N, indenter.force_N, "force_N", "N", FORCE_MODEL_ERROR)
    d = level(depth_m, indenter.displacement_noise_rms_m, indenter.displacement_m, "depth_m", "m", DEPTH_FLOOR)
    if tracking_m is not None:
        tr, sources["tracking_m"] = float(tracking_m), "given"
    else:
        spacing = flow["spacing_m"].values if "spacing_m" in flow else None
        dt = flow.time_end.values - flow.time_start.values
        tr, sources["tracking_m"] = tracking_noise(flow.u_of.values, flow.c_of.values, dt, spacing)
    log.info("noise: force %.3g N, depth %.3g m, tracking %.3g m (%s)", f, d, tr, sources)
    return NoiseModel(f, d, tr, sources)
