"""The curvilinear (Frenet) road frame of a scene: a smooth, arclength-parameterised reference path
fitted to the lanelet geometry, every point as (s, d) and every heading relative to the path, and
lanes as lateral intervals that begin and end along s.

Coordinates: ``s`` arclength along the path (m, 0 at the foot of the scene's rotated-frame origin,
increasing in the direction of travel), ``d`` signed distance from the path (m, positive LEFT),
heading relative to the path's tangent (rad). The projection is the exact foot point (Newton on
the path's parameter), so ``to_world(project(p)) == p`` to rounding; it is unique only within the
path's radius of curvature, and the frame refuses points whose offset comes near it.

Lanes: each lanelet boundary is mapped to (s, d). A lane is present at ``s`` while it is at least
``min_lane_width_m`` wide and joined to the carriageway: where two lanes that are neighbours in d
separate by more than ``gore_gap_m`` (the gore of an on- or off-ramp), the side with fewer lanes
has left the road there. So an on-ramp lane begins where it joins the road and an acceleration or
exit lane ends where it narrows away or separates.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.interpolate import BSpline

from .tracks import FrenetLane

__all__ = ["FrenetConfig", "FrameRefusal", "ReferencePath", "check_offsets", "fit_reference", "lane_extents"]


@dataclass(frozen=True)
class FrenetConfig:
    """Parameters of the curvilinear frame (m, rad)."""

    sample_m: float = 0.25
    """Spacing of the stored arclength table (m)."""
    gore_gap_m: float = 0.5
    """Neighbouring lanes farther apart than this (m) are separated (a gore): the smaller side has left the road."""
    min_lane_width_m: float = 2.0
    """A lane narrower than this (m) has not begun or has ended."""
    max_residual_m: float = 1.0
    """Worst deviation (half peak-to-peak, m) of a lane boundary from d = const over a lane piece
    that the frame accepts; beyond it the scene is refused."""
    max_turn_rad: float = 1.0
    """Largest heading change (rad) of the reference path over the scene (a path turning more is
    not a graph over one direction: refused)."""
    max_offset_curvature: float = 0.5
    """Refuse points whose |d| times the path curvature at their foot exceeds this (the
    projection stops being unique at 1)."""
    lane_step_m: float = 1.0
    """Spacing (m) at which lane extents are evaluated."""
    knot_m: float = 25.0
    """Knot spacing (m) of the reference path's cubic spline."""
    smoothing: float = 1e-3
    """Weight of the spline's second-difference penalty (m^-2 against squared boundary residuals)."""
    reject_m: float = 0.3
    """Boundaries deviating more than this (m) from the fitted shape do not follow the road (ramp
    tapers, gores) and are left out of the next fit."""
    margin_m: float = 60.0
    """The reference path extends this far (m) beyond the lanelets at both ends."""
    edge_margin_m: float = 5.0
    """A lane whose extent starts (ends) more than this (m) after the start (before the end) of the
    lane map begins (ends) inside the scene."""

    def validate(self) -> "FrenetConfig":
        for name in ("sample_m", "gore_gap_m", "min_lane_width_m", "max_residual_m", "max_turn_rad",
                     "max_offset_curvature", "lane_step_m", "edge_margin_m", "knot_m", "smoothing", "reject_m",
                     "margin_m"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v > 0):
                raise ValueError(f"FrenetConfig.{name} must be finite and > 0, got {v!r}")
        if self.max_offset_curvature >= 1.0:
            raise ValueError(f"FrenetConfig.max_offset_curvature must be < 1, got {self.max_offset_curvature!r}")
        return self


class FrameRefusal(Exception):
    """The scene's geometry cannot be represented in the frame (the reader turns it into a
    ``DataError`` naming the file)."""


def fit_reference(lanelets: list[tuple[np.ndarray, np.ndarray]], cfg: FrenetConfig) -> BSpline:
    """The road's shape y = f(x) in the rotated frame, f(0) = 0: a cubic P-spline (uniform knots
    about every ``knot_m``) fitted by least squares to every lanelet boundary [P, 2] (m) with one lateral
    offset per boundary, a second-difference penalty for smoothness, and boundaries that do not
    follow the road (residual > ``reject_m``) left out one at a time, worst first (at least two are
    kept)."""
    polys = [p for l, r in lanelets for p in (l, r)]
    xs = np.concatenate([p[:, 0] for p in polys])
    lo, hi = float(xs.min()) - cfg.margin_m, float(xs.max()) + cfg.margin_m
    n_int = max(int(math.ceil((hi - lo) / cfg.knot_m)), 1)
    h = (hi - lo) / n_int
    t = lo + h * np.arange(-3, n_int + 4)  # uniform knots (a P-spline): coefficient differences ~ h^2 f''
    n_c = t.shape[0] - 4
    pen = np.diff(np.eye(n_c), n=2, axis=0) * math.sqrt(cfg.smoothing)
    keep = list(range(len(polys)))
    coef = np.zeros(n_c)
    for _ in range(len(polys)):
        rows, rhs = [], []
        for k, i in enumerate(keep):
            p = polys[i]
            a = np.zeros((p.shape[0], n_c + len(keep)))
            a[:, :n_c] = BSpline.design_matrix(p[:, 0], t, 3).toarray()
            a[:, n_c + k] = 1.0
            rows.append(a)
            rhs.append(p[:, 1])
        origin = np.zeros((1, n_c + len(keep)))
        origin[0, :n_c] = BSpline.design_matrix(np.asarray([0.0]), t, 3).toarray()[0] if lo <= 0.0 <= hi else 0.0
        origin *= 1e3
        penalty = np.concatenate([pen, np.zeros((pen.shape[0], len(keep)))], axis=1)
        sol = np.linalg.lstsq(np.concatenate(rows + [origin, penalty]),
                              np.concatenate(rhs + [np.zeros(1), np.zeros(pen.shape[0])]), rcond=None)[0]
        coef = sol[:n_c]
        spline = BSpline(t, coef, 3, extrapolate=False)
        worst = [float(np.max(np.abs(polys[i][:, 1] - spline(polys[i][:, 0]) - sol[n_c + k])))
                 for k, i in enumerate(keep)]
        k_worst = int(np.argmax(worst))
        if worst[k_worst] <= cfg.reject_m or len(keep) <= 2:
            break
        keep = keep[:k_worst] + keep[k_worst + 1:]  # one at a time: a ramp distorts the first fits
    return BSpline(t, coef, 3, extrapolate=False)


@dataclass(frozen=True)
class ReferencePath:
    """Reference path: the curve y = f(x) (``shape``, a cubic spline) in a frame rotated by
    ``theta`` (world direction ``theta`` -> +x), over rotated-frame x in [``x_lo``, ``x_hi``] (m).

    ``u`` [M], ``s`` [M]: the arclength table (rotated-frame x -> s, m), ``s`` = 0 at u = 0.
    """

    theta: float
    shape: BSpline
    x_lo: float
    x_hi: float
    u: np.ndarray
    s: np.ndarray

    @staticmethod
    def build(theta: float, shape: BSpline, cfg: FrenetConfig) -> "ReferencePath":
        """Tabulate the arclength of ``shape`` over its knot range (composite Simpson per interval).

        Raises:
            FrameRefusal: the path turns by more than ``cfg.max_turn_rad``.
        """
        x_lo, x_hi = float(shape.t[3]), float(shape.t[-4])
        n = max(int(math.ceil((x_hi - x_lo) / cfg.sample_m)), 2)
        u = np.linspace(x_lo, x_hi, n + 1)

        def speed(x: np.ndarray) -> np.ndarray:
            return np.sqrt(1.0 + shape(x, 1) ** 2)

        h = np.diff(u)
        seg = h / 6.0 * (speed(u[:-1]) + 4.0 * speed(0.5 * (u[:-1] + u[1:])) + speed(u[1:]))
        s = np.concatenate([[0.0], np.cumsum(seg)])
        s -= np.interp(0.0, u, s)
        turn = float(np.ptp(np.arctan(shape(u, 1))))
        if turn > cfg.max_turn_rad:
            raise FrameRefusal(f"the reference path turns by {math.degrees(turn):.0f} deg over the scene "
                               f"(the frame follows at most {math.degrees(cfg.max_turn_rad):.0f} deg)")
        return ReferencePath(theta=float(theta), shape=shape, x_lo=x_lo, x_hi=x_hi, u=u, s=s)

    # -- geometry of the path ------------------------------------------------------------------
    def _rotate(self, pts: np.ndarray) -> np.ndarray:
        c, s = math.cos(self.theta), math.sin(self.theta)
        return np.stack([c * pts[:, 0] + s * pts[:, 1], -s * pts[:, 0] + c * pts[:, 1]], axis=1)

    def _unrotate(self, pts: np.ndarray) -> np.ndarray:
        c, s = math.cos(self.theta), math.sin(self.theta)
        return np.stack([c * pts[:, 0] - s * pts[:, 1], s * pts[:, 0] + c * pts[:, 1]], axis=1)

    def _f(self, u: np.ndarray, nu: int = 0) -> np.ndarray:
        """Shape or its ``nu``-th derivative at ``u``, clamped to the path's range (NaN-free)."""
        return self.shape(np.clip(u, self.x_lo, self.x_hi), nu)

    def tangent_angle(self, u: np.ndarray) -> np.ndarray:
        """World heading (rad) of the path at rotated-frame parameter ``u`` [N]."""
        return self.theta + np.arctan(self._f(u, 1))

    def curvature(self, u: np.ndarray) -> np.ndarray:
        """Signed curvature (1/m, positive turning left) at ``u`` [N]."""
        f1, f2 = self._f(u, 1), self._f(u, 2)
        return f2 / (1.0 + f1 * f1) ** 1.5

    def s_of_u(self, u: np.ndarray) -> np.ndarray:
        """Arclength (m) at rotated-frame parameter ``u`` [N] (m)."""
        return np.interp(u, self.u, self.s)

    def u_of_s(self, s: np.ndarray) -> np.ndarray:
        """Rotated-frame parameter (m) at arclength ``s`` [N] (m)."""
        return np.interp(s, self.s, self.u)

    # -- the map and its inverse ----------------------------------------------------------------
    def project(self, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """World points [N, 2] (m) -> (s [N], d [N], u [N]): arclength and signed left offset of
        the exact foot point, and its rotated-frame parameter.

        Raises:
            FrameRefusal: a point whose foot lies beyond the ends of the path or whose projection
            did not converge.
        """
        pts = np.asarray(pts, dtype=np.float64)
        q = self._rotate(pts)
        px, py = q[:, 0], q[:, 1]
        u = np.clip(px.copy(), self.x_lo, self.x_hi)
        for _ in range(50):
            f, f1, f2 = self._f(u), self._f(u, 1), self._f(u, 2)
            g = (px - u) + (py - f) * f1  # (p - c(u)) . c'(u) = 0 at the foot
            gp = -1.0 - f1 * f1 + (py - f) * f2
            step = g / gp
            u = u - step
            if np.all(np.abs(step) < 1e-10):
                break
        f, f1 = self._f(u), self._f(u, 1)
        g = (px - u) + (py - f) * f1
        d = (-(px - u) * f1 + (py - f)) / np.sqrt(1.0 + f1 * f1)  # (p - c(u)) . n, n = (-f1, 1) / |.|
        bad = ~np.isfinite(u) | ~(np.abs(g) <= 1e-7 * (1.0 + np.abs(py - f)))
        if np.any(bad):
            i = int(np.flatnonzero(bad)[0])
            raise FrameRefusal(f"the projection of point ({pts[i, 0]:.2f}, {pts[i, 1]:.2f}) m onto the reference "
                               "path did not converge")
        outside = (u <= self.x_lo) | (u >= self.x_hi)
        if np.any(outside):
            i = int(np.flatnonzero(outside)[0])
            raise FrameRefusal(f"point ({pts[i, 0]:.2f}, {pts[i, 1]:.2f}) m lies beyond the ends of the reference "
                               f"path (rotated-frame x {px[i]:.1f} m, path {self.x_lo:.1f}..{self.x_hi:.1f} m)")
        return self.s_of_u(u), d, u

    def to_world(self, s: np.ndarray, d: np.ndarray) -> np.ndarray:
        """(s [N], d [N]) -> world points [N, 2] (m): the inverse of :meth:`project`."""
        u = self.u_of_s(np.asarray(s, dtype=np.float64))
        f, f1 = self._f(u), self._f(u, 1)
        norm = np.sqrt(1.0 + f1 * f1)
        d = np.asarray(d, dtype=np.float64)
        return self._unrotate(np.stack([u - d * f1 / norm, f + d / norm], axis=1))


def check_offsets(path: ReferencePath, u: np.ndarray, d: np.ndarray, cfg: FrenetConfig) -> None:
    """Refuse points whose offset is not small against the path's radius of curvature."""
    kd = np.abs(path.curvature(u) * d)
    if np.any(kd > cfg.max_offset_curvature):
        i = int(np.argmax(kd))
        raise FrameRefusal(f"offset {d[i]:.1f} m at s {path.s_of_u(u[i:i + 1])[0]:.1f} m is "
                           f"{kd[i]:.2f} of the radius of curvature (at most {cfg.max_offset_curvature:g}): "
                           "the projection onto the reference path is not unique there")


def lane_extents(lanes: list[tuple[np.ndarray, np.ndarray]], cfg: FrenetConfig) -> list[FrenetLane]:
    """Where each lane lies on the carriageway.

    ``lanes``: per lane, its (left, right) boundaries in (s, d) ([P, 2], [Q, 2], any order). A lane
    is on the road at s while it is at least ``min_lane_width_m`` wide and, among the lanes present
    at s sorted by d, not on the smaller side of a gap wider than ``gore_gap_m``. Returns one
    :class:`FrenetLane` per input lane (``s_begin > s_end`` when it is never on the road).
    """
    sorted_b = []
    for left, right in lanes:
        lo = np.argsort(left[:, 0], kind="stable")
        ro = np.argsort(right[:, 0], kind="stable")
        sorted_b.append((left[lo], right[ro]))
    lo_all = min(min(l[0, 0], r[0, 0]) for l, r in sorted_b)
    hi_all = max(max(l[-1, 0], r[-1, 0]) for l, r in sorted_b)
    grid = np.arange(math.floor(lo_all), math.ceil(hi_all) + cfg.lane_step_m, cfg.lane_step_m)
    n = len(sorted_b)
    on = np.zeros((n, grid.shape[0]), dtype=bool)
    dl = np.full((n, grid.shape[0]), np.nan)
    dr = np.full((n, grid.shape[0]), np.nan)
    for k, (left, right) in enumerate(sorted_b):
        a = max(left[0, 0], right[0, 0])
        b = min(left[-1, 0], right[-1, 0])
        m = (grid >= a) & (grid <= b)
        dl[k, m] = np.interp(grid[m], left[:, 0], left[:, 1])
        dr[k, m] = np.interp(grid[m], right[:, 0], right[:, 1])
        on[k] = m & (dl[k] - dr[k] >= cfg.min_lane_width_m)
    for j in range(grid.shape[0]):
        present = np.flatnonzero(on[:, j])
        if present.shape[0] < 2:
            continue
        order = present[np.argsort(0.5 * (dl[present, j] + dr[present, j]), kind="stable")]
        # Groups of lanes joined to each other (gaps within gore_gap_m; overlapping pieces join).
        groups: list[list[int]] = [[int(order[0])]]
        for a, b in zip(order[:-1], order[1:]):
            if dr[b, j] - dl[a, j] > cfg.gore_gap_m:
                groups.append([int(b)])
            else:
                groups[-1].append(int(b))
        if len(groups) > 1:
            main = max(range(len(groups)), key=lambda g: (len(groups[g]), -g))
            for g, members in enumerate(groups):
                if g != main:
                    on[members, j] = False
    out = []
    for k in range(n):
        idx = np.flatnonzero(on[k])
        if idx.size == 0:
            empty = np.zeros((0, 2))
            out.append(FrenetLane(s_begin=math.inf, s_end=-math.inf, begins=False, ends=False, left=empty,
                                  right=empty))
            continue
        # The longest run of consecutive samples on the road.
        breaks = np.flatnonzero(np.diff(idx) > 1)
        starts = np.concatenate([[0], breaks + 1])
        stops = np.concatenate([breaks, [idx.size - 1]])
        r = int(np.argmax(stops - starts))
        s0, s1 = float(grid[idx[starts[r]]]), float(grid[idx[stops[r]]])
        keep = (grid >= s0) & (grid <= s1)
        left = np.stack([grid[keep], dl[k, keep]], axis=1)
        right = np.stack([grid[keep], dr[k, keep]], axis=1)
        out.append(FrenetLane(s_begin=s0, s_end=s1, begins=bool(s0 > lo_all + cfg.edge_margin_m),
                              ends=bool(s1 < hi_all - cfg.edge_margin_m), left=left, right=right))
    return out
