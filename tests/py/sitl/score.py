"""Scoring of the closed loop: geodetic to local frames (WGS-84, no flat-earth
shortcut) and estimate-vs-truth errors matched by host receive time."""
import math

import numpy as np

A = 6378137.0
F = 1 / 298.257223563
E2 = F * (2 - F)


def ecef(lat_deg, lon_deg, alt_m):
    lat, lon = np.radians(lat_deg), np.radians(lon_deg)
    n = A / np.sqrt(1 - E2 * np.sin(lat) ** 2)
    return np.stack([(n + alt_m) * np.cos(lat) * np.cos(lon),
                     (n + alt_m) * np.cos(lat) * np.sin(lon),
                     (n * (1 - E2) + alt_m) * np.sin(lat)], axis=-1)


def ned(lat, lon, alt, origin):
    """Arrays of lat/lon (deg) and alt (m) to NED metres about origin (lat, lon, alt)."""
    la0, lo0, _ = origin
    d = ecef(np.asarray(lat), np.asarray(lon), np.asarray(alt)) - ecef(*origin)
    sl, cl = math.sin(math.radians(la0)), math.cos(math.radians(la0))
    so, co = math.sin(math.radians(lo0)), math.cos(math.radians(lo0))
    e = -so * d[..., 0] + co * d[..., 1]
    n = -sl * co * d[..., 0] - sl * so * d[..., 1] + cl * d[..., 2]
    u = cl * co * d[..., 0] + cl * so * d[..., 1] + sl * d[..., 2]
    return np.stack([n, e, -u], axis=-1)


def interp(t_query, t, xyz, max_gap):
    """Truth at the query times (linear), NaN where the truth has a gap > max_gap or
    does not cover the time."""
    t = np.asarray(t)
    out = np.full((len(t_query), 3), np.nan)
    if len(t) < 2:
        return out
    for k in range(3):
        out[:, k] = np.interp(t_query, t, xyz[:, k], left=np.nan, right=np.nan)
    i = np.clip(np.searchsorted(t, t_query), 1, len(t) - 1)
    gap = t[i] - t[i - 1]
    out[gap > max_gap] = np.nan
    return out


def _stats(e):
    if len(e) == 0:
        return None
    h = np.hypot(e[:, 0], e[:, 1])
    return {"n": int(len(e)),
            "rmse_h": round(float(np.sqrt(np.mean(h ** 2))), 3),
            "max_h": round(float(np.max(h)), 3),
            "rmse_v": round(float(np.sqrt(np.mean(e[:, 2] ** 2))), 3),
            "max_v": round(float(np.max(np.abs(e[:, 2]))), 3),
            "mean": [round(float(x), 3) for x in np.mean(e, axis=0)]}


def errors(est_t, est_ned, truth_t, truth_ned, phases, t_ref, lag_s=0.0, max_gap=0.5):
    """Per phase (name -> (t0, t1), host monotonic seconds) the horizontal/vertical
    error of the estimate against truth, raw and with the constant offset at t_ref
    (the median error over the second before it: the arming) removed."""
    est_t = np.asarray(est_t, float)
    est = np.asarray(est_ned, float).reshape(-1, 3)
    if len(est_t) == 0 or len(truth_t) < 2:
        return {"error": "no samples"}
    tru = interp(est_t - lag_s, truth_t, np.asarray(truth_ned, float), max_gap)
    e = est - tru
    ok = np.all(np.isfinite(e), axis=1)
    offset = None
    if t_ref is not None:
        w = ok & (est_t >= t_ref - 1.0) & (est_t <= t_ref)
        if w.sum() >= 3:
            offset = np.median(e[w], axis=0)
    out = {"offset_at_arming": None if offset is None else [round(float(x), 3) for x in offset]}
    for name, (t0, t1) in phases.items():
        m = ok & (est_t >= t0) & (est_t <= t1)
        out[name] = {"raw": _stats(e[m]),
                     "offset_removed": None if offset is None else _stats(e[m] - offset)}
    return out


def best_lag(est_t, est_ned, truth_t, truth_ned, t0, t1, lags=np.arange(-0.3, 0.501, 0.02)):
    """The host-time lag of the estimate behind truth that minimises the horizontal RMSE
    over [t0, t1] (a constant offset removed): how late the estimate arrives."""
    est_t = np.asarray(est_t, float)
    est = np.asarray(est_ned, float).reshape(-1, 3)
    m = (est_t >= t0) & (est_t <= t1)
    if m.sum() < 20:
        return None
    best = None
    for lag in lags:
        tru = interp(est_t[m] - lag, truth_t, np.asarray(truth_ned, float), 0.5)
        e = est[m] - tru
        ok = np.all(np.isfinite(e), axis=1)
        if ok.sum() < 20:
            continue
        e = e[ok] - np.mean(e[ok], axis=0)
        r = float(np.sqrt(np.mean(e[:, 0] ** 2 + e[:, 1] ** 2)))
        if best is None or r < best[1]:
            best = (float(lag), r)
    return None if best is None else {"lag_s": round(best[0], 3), "rmse_h_centered": round(best[1], 3)}
