//! The straight lane map of a CommonRoad scene in the road frame, as the data pipeline builds
//! it (`nudge_train.data.commonroad._lane_map` and `tracks.LaneMap`): pieces of x over which
//! the same lanelets exist, each with its ascending lane boundaries, and the bounds as
//! polylines for the local straightness check.

use std::path::Path;

use super::error::CommonRoadError;
use super::frame::interp;

/// Pieces shorter than this (m) between lanelet start/end points are skipped.
pub const MIN_PIECE: f64 = 1.0;
/// Lanelets overlapping laterally by more than this (m) at one x are one lane.
pub const MERGE_OVERLAP: f64 = 0.5;
/// Neighbouring pieces whose boundaries differ by less than this (m) are merged ...
pub const SAME_BOUNDS: f64 = 0.2;
/// ... when they are at most this far apart (m).
pub const PIECE_GAP: f64 = 1.5;
/// A lanelet narrower than this (m) is not on the carriageway there (it has not begun or has
/// ended: a ramp's taper), as the data pipeline's `min_lane_width_m`.
pub const MIN_LANE_WIDTH: f64 = 2.0;
/// Neighbouring lanelets farther apart than this (m) are separated (a gore): the side with
/// fewer lanelets has left the carriageway there, as the pipeline's `gore_gap_m`.
pub const GORE_GAP: f64 = 0.5;
/// Spacing (m) of the samples at which [`on_carriageway`] decides.
pub const LANE_STEP: f64 = 1.0;
/// Points per piece at which the bounds are sampled.
const PIECE_SAMPLES: usize = 9;

/// One lanelet in the road frame: left and right bounds (x ascending, m) and its name.
#[derive(Debug, Clone)]
pub struct RoadLanelet {
    /// The lanelet's id.
    pub id: String,
    /// 1-based line of the lanelet in the file.
    pub line: usize,
    /// Left bound (x, y) (m), sorted by x.
    pub left: Vec<[f64; 2]>,
    /// Right bound (x, y) (m), sorted by x.
    pub right: Vec<[f64; 2]>,
}

/// Lane boundaries over x pieces, and the bound polylines (road frame, m).
#[derive(Debug, Clone, PartialEq)]
pub struct LaneMap {
    /// (x0, x1, ascending boundaries `[L + 1]`) (m).
    pub pieces: Vec<(f64, f64, Vec<f64>)>,
    /// Every lanelet bound, x ascending (m).
    pub polylines: Vec<Vec<[f64; 2]>>,
}

/// Sorts a polyline by x (stable, as numpy's stable argsort).
pub(crate) fn sorted_by_x(mut p: Vec<[f64; 2]>) -> Vec<[f64; 2]> {
    p.sort_by(|a, b| a[0].total_cmp(&b[0]));
    p
}

/// y of the x-sorted polyline `p` at x (constant beyond its ends).
fn y_at(p: &[[f64; 2]], x: f64) -> f64 {
    let xs: Vec<f64> = p.iter().map(|q| q[0]).collect();
    let ys: Vec<f64> = p.iter().map(|q| q[1]).collect();
    interp(x, &xs, &ys)
}

fn extent(ll: &RoadLanelet) -> (f64, f64) {
    let xs = ll.left.iter().chain(&ll.right).map(|p| p[0]);
    xs.fold((f64::INFINITY, f64::NEG_INFINITY), |(l, h), x| {
        (l.min(x), h.max(x))
    })
}

/// Python's `round(v, 3)` for the breakpoints (m).
fn round3(v: f64) -> f64 {
    (v * 1000.0).round() / 1000.0
}

/// The (right, left) mean y (m) of each lanelet present over [x0, x1], or the error of the
/// first whose left bound is not left of its right bound.
fn lateral_spans(
    lanelets: &[RoadLanelet],
    present: &[usize],
    (x0, x1): (f64, f64),
    path: &Path,
) -> Result<Vec<(f64, f64)>, CommonRoadError> {
    #[allow(clippy::cast_precision_loss)]
    let grid: Vec<f64> = (0..PIECE_SAMPLES)
        .map(|i| x0 + (x1 - x0) * i as f64 / (PIECE_SAMPLES - 1) as f64)
        .collect();
    #[allow(clippy::cast_precision_loss)]
    let mean =
        |p: &[[f64; 2]]| grid.iter().map(|&x| y_at(p, x)).sum::<f64>() / PIECE_SAMPLES as f64;
    let mut rows = Vec::with_capacity(present.len());
    for &i in present {
        let ll = &lanelets[i];
        let (yl, yr) = (mean(&ll.left), mean(&ll.right));
        if yl <= yr {
            return Err(CommonRoadError::Field {
                path: path.to_path_buf(),
                line: ll.line,
                element: format!("lanelet {} leftBound", ll.id),
                reason: format!(
                    "left bound is not left of the right bound over x {x0:.1}..{x1:.1} m (road frame)"
                ),
            });
        }
        rows.push((yr, yl));
    }
    rows.sort_by(|a, b| a.0.total_cmp(&b.0).then(a.1.total_cmp(&b.1)));
    Ok(rows)
}

/// Lane boundaries from the sorted (right, left) spans: overlapping spans merged, the
/// boundary between neighbours their midpoint.
fn boundaries(rows: &[(f64, f64)]) -> Vec<f64> {
    let mut merged: Vec<[f64; 2]> = Vec::new();
    for &(r, l) in rows {
        match merged.last_mut() {
            Some(m) if r < m[1] - MERGE_OVERLAP => m[1] = m[1].max(l),
            _ => merged.push([r, l]),
        }
    }
    let mut b = vec![merged[0][0]];
    b.extend(merged.windows(2).map(|w| 0.5 * (w[0][1] + w[1][0])));
    b.push(merged[merged.len() - 1][1]);
    b
}

/// Neighbouring pieces with the same lanes merged (the first piece's boundaries kept).
fn merge_pieces(pieces: Vec<(f64, f64, Vec<f64>)>) -> Vec<(f64, f64, Vec<f64>)> {
    let mut out: Vec<(f64, f64, Vec<f64>)> = Vec::with_capacity(pieces.len());
    for (x0, x1, b) in pieces {
        if let Some(last) = out.last_mut() {
            let same = last.2.len() == b.len()
                && last
                    .2
                    .iter()
                    .zip(&b)
                    .all(|(p, q)| (p - q).abs() < SAME_BOUNDS);
            if same && (last.1 - x0).abs() < PIECE_GAP {
                last.1 = x1;
                continue;
            }
        }
        out.push((x0, x1, b));
    }
    out
}

/// The parts of `lanelets` (road frame) that lie on the carriageway, as the data pipeline's
/// curvilinear lane map decides (`nudge_train.data.frenet.lane_extents`, per lanelet): on a
/// grid of [`LANE_STEP`], a lanelet is on the road where it is at least [`MIN_LANE_WIDTH`]
/// wide and, among the lanelets there sorted by their centre, not on the smaller side of a
/// gap wider than [`GORE_GAP`]; each lanelet is cut to its longest run on the road (bounds
/// resampled on the grid) and dropped when it has none. In the curvilinear frame the lanes
/// are then lines y = const where they are on the road, whereas a ramp's taper or a gore
/// bends away.
#[must_use]
#[allow(
    clippy::cast_possible_truncation,
    clippy::cast_sign_loss,
    clippy::cast_precision_loss
)]
pub fn on_carriageway(lanelets: &[RoadLanelet]) -> Vec<RoadLanelet> {
    if lanelets.is_empty() {
        return Vec::new();
    }
    let ext: Vec<(f64, f64)> = lanelets
        .iter()
        .map(|ll| {
            (
                ll.left[0][0].max(ll.right[0][0]),
                ll.left[ll.left.len() - 1][0].min(ll.right[ll.right.len() - 1][0]),
            )
        })
        .collect();
    let lo = lanelets
        .iter()
        .map(|ll| ll.left[0][0].min(ll.right[0][0]))
        .fold(f64::INFINITY, f64::min)
        .floor();
    let hi = lanelets
        .iter()
        .map(|ll| ll.left[ll.left.len() - 1][0].max(ll.right[ll.right.len() - 1][0]))
        .fold(f64::NEG_INFINITY, f64::max)
        .ceil();
    let n_grid = ((hi - lo) / LANE_STEP).floor() as usize + 1;
    let grid: Vec<f64> = (0..n_grid).map(|j| lo + j as f64 * LANE_STEP).collect();
    let n = lanelets.len();
    let mut on = vec![vec![false; n_grid]; n];
    let mut dl = vec![vec![f64::NAN; n_grid]; n];
    let mut dr = vec![vec![f64::NAN; n_grid]; n];
    for (k, ll) in lanelets.iter().enumerate() {
        for (j, &x) in grid.iter().enumerate() {
            if x >= ext[k].0 && x <= ext[k].1 {
                dl[k][j] = y_at(&ll.left, x);
                dr[k][j] = y_at(&ll.right, x);
                on[k][j] = dl[k][j] - dr[k][j] >= MIN_LANE_WIDTH;
            }
        }
    }
    for j in 0..n_grid {
        let mut present: Vec<usize> = (0..n).filter(|&k| on[k][j]).collect();
        if present.len() < 2 {
            continue;
        }
        present.sort_by(|&a, &b| (dl[a][j] + dr[a][j]).total_cmp(&(dl[b][j] + dr[b][j])));
        let mut groups: Vec<Vec<usize>> = vec![vec![present[0]]];
        for w in present.windows(2) {
            if dr[w[1]][j] - dl[w[0]][j] > GORE_GAP {
                groups.push(vec![w[1]]);
            } else if let Some(g) = groups.last_mut() {
                g.push(w[1]);
            }
        }
        if groups.len() > 1 {
            let main = (0..groups.len())
                .max_by(|&a, &b| groups[a].len().cmp(&groups[b].len()).then(b.cmp(&a)))
                .unwrap_or(0);
            for (g, members) in groups.iter().enumerate() {
                if g != main {
                    members.iter().for_each(|&k| on[k][j] = false);
                }
            }
        }
    }
    let mut out = Vec::new();
    for (k, ll) in lanelets.iter().enumerate() {
        // The longest run of consecutive samples on the road.
        let (mut best, mut start) = ((0, 0), None);
        for (j, here) in on[k].iter().copied().chain([false]).enumerate() {
            match (here, start) {
                (true, None) => start = Some(j),
                (false, Some(s0)) => {
                    if j - s0 > best.1 - best.0 {
                        best = (s0, j);
                    }
                    start = None;
                }
                _ => {}
            }
        }
        if best.1 - best.0 < 2 {
            continue;
        }
        let cut = |d: &[f64]| {
            (best.0..best.1)
                .map(|j| [grid[j], d[j]])
                .collect::<Vec<_>>()
        };
        out.push(RoadLanelet {
            id: ll.id.clone(),
            line: ll.line,
            left: cut(&dl[k]),
            right: cut(&dr[k]),
        });
    }
    out
}

/// Lanes whose centres differ by less than this (m) in neighbouring pieces are one lane
/// ([`LaneMap::lanes_with_extents`]).
pub const SAME_LANE: f64 = 1.0;
/// A lane that begins (ends) more than this (m) after the start (before the end) of the lane
/// map begins (ends) inside the scene, as the pipeline's `edge_margin_m`.
pub const EDGE_MARGIN: f64 = 5.0;

/// One lane over the pieces ([`LaneMap::lanes_with_extents`]): right and left bound (m, at
/// the first piece it appears in) and where along x it begins and ends (m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LaneSpan {
    /// Right bound y (m).
    pub right: f64,
    /// Left bound y (m).
    pub left: f64,
    /// First x (m) of the pieces it runs through.
    pub begin: f64,
    /// Last x (m).
    pub end: f64,
    /// It begins inside the lane map (not at its start).
    pub begins: bool,
    /// It ends inside the lane map (not at its end).
    pub ends: bool,
}

impl LaneMap {
    /// Every lane that runs through the piece at road x `x` or joins the road later or ends
    /// earlier (curvilinear frame, where lanes are lines y = const): the lanes of the piece at
    /// `x`, followed forward and backward through neighbouring pieces (a lane of the next
    /// piece whose centre is within [`SAME_LANE`] of one is that lane; one that is not and
    /// does not overlap the others is a lane that begins there), sorted right to left, each
    /// with its extent.
    #[must_use]
    pub fn lanes_with_extents(&self, x: f64) -> Vec<LaneSpan> {
        let n = self.pieces.len();
        let dist = |p: &(f64, f64, Vec<f64>)| (x - p.0).max(0.0) + (p.1 - x).min(0.0).abs();
        let k0 = (0..n)
            .min_by(|&a, &b| dist(&self.pieces[a]).total_cmp(&dist(&self.pieces[b])))
            .unwrap_or(0);
        let spans = |b: &[f64]| -> Vec<(f64, f64)> { b.windows(2).map(|w| (w[0], w[1])).collect() };
        let (x0, x1, b0) = &self.pieces[k0];
        let mut lanes: Vec<LaneSpan> = spans(b0)
            .into_iter()
            .map(|(r, l)| LaneSpan {
                right: r,
                left: l,
                begin: *x0,
                end: *x1,
                begins: false,
                ends: false,
            })
            .collect();
        let join = |lanes: &mut Vec<LaneSpan>, piece: &(f64, f64, Vec<f64>), forward: bool| {
            let mut seen = vec![false; lanes.len()];
            for (r, l) in spans(&piece.2) {
                let c = 0.5 * (r + l);
                let hit = lanes
                    .iter()
                    .position(|ln| (0.5 * (ln.right + ln.left) - c).abs() < SAME_LANE);
                match hit {
                    Some(i) => {
                        let ln = &mut lanes[i];
                        let touches = if forward {
                            (piece.0 - ln.end).abs() < PIECE_GAP
                        } else {
                            (ln.begin - piece.1).abs() < PIECE_GAP
                        };
                        if touches {
                            if forward {
                                ln.end = piece.1;
                            } else {
                                ln.begin = piece.0;
                            }
                            seen[i] = true;
                        }
                    }
                    None => {
                        let overlaps = lanes
                            .iter()
                            .any(|ln| r < ln.left - MERGE_OVERLAP && l > ln.right + MERGE_OVERLAP);
                        if !overlaps {
                            lanes.push(LaneSpan {
                                right: r,
                                left: l,
                                begin: piece.0,
                                end: piece.1,
                                begins: false,
                                ends: false,
                            });
                            seen.push(true);
                        }
                    }
                }
            }
        };
        for piece in &self.pieces[k0 + 1..] {
            join(&mut lanes, piece, true);
        }
        for piece in self.pieces[..k0].iter().rev() {
            join(&mut lanes, piece, false);
        }
        let (lo, hi) = (self.pieces[0].0, self.pieces[n - 1].1);
        for ln in &mut lanes {
            ln.begins = ln.begin > lo + EDGE_MARGIN;
            ln.ends = ln.end < hi - EDGE_MARGIN;
        }
        lanes.sort_by(|a, b| (a.right + a.left).total_cmp(&(b.right + b.left)));
        lanes
    }

    /// Builds the lane map of `lanelets` (road frame) of the file `path`.
    ///
    /// # Errors
    /// [`CommonRoadError::Field`] when a lanelet's left bound is not left of its right bound;
    /// [`CommonRoadError::Unsupported`] when the lanelets give overlapping or inverted lanes,
    /// or no lanes at all.
    pub fn build(lanelets: &[RoadLanelet], path: &Path) -> Result<Self, CommonRoadError> {
        let extents: Vec<(f64, f64)> = lanelets.iter().map(extent).collect();
        let mut xs: Vec<f64> = extents
            .iter()
            .flat_map(|&(a, b)| [round3(a), round3(b)])
            .collect();
        xs.sort_by(f64::total_cmp);
        xs.dedup();
        let mut pieces = Vec::new();
        for w in xs.windows(2) {
            let (x0, x1) = (w[0], w[1]);
            if x1 - x0 < MIN_PIECE {
                continue;
            }
            let mid = 0.5 * (x0 + x1);
            let present: Vec<usize> = (0..lanelets.len())
                .filter(|&i| extents[i].0 <= mid + 1e-6 && extents[i].1 >= mid - 1e-6)
                .collect();
            if present.is_empty() {
                continue;
            }
            let rows = lateral_spans(lanelets, &present, (x0, x1), path)?;
            let b = boundaries(&rows);
            if b.windows(2).any(|p| p[1] <= p[0]) {
                let list: Vec<String> = b.iter().map(|v| format!("{v:.2}")).collect();
                return Err(CommonRoadError::Unsupported {
                    path: path.to_path_buf(),
                    reason: format!(
                        "lanelets give overlapping or inverted lanes over x {x0:.1}..{x1:.1} m \
                         (boundaries {} m are not ascending)",
                        list.join(", ")
                    ),
                });
            }
            pieces.push((x0, x1, b));
        }
        if pieces.is_empty() {
            return Err(CommonRoadError::Unsupported {
                path: path.to_path_buf(),
                reason: "the lanelet map has no lanes".into(),
            });
        }
        let polylines = lanelets
            .iter()
            .flat_map(|ll| [ll.left.clone(), ll.right.clone()])
            .collect();
        Ok(Self {
            pieces: merge_pieces(pieces),
            polylines,
        })
    }

    /// Ascending lane boundaries `[L + 1]` (m) at road x (m): the piece covering x, else the
    /// nearest piece.
    #[must_use]
    pub fn bounds_at(&self, x: f64) -> &[f64] {
        if let Some(p) = self.pieces.iter().find(|p| p.0 <= x && x <= p.1) {
            return &p.2;
        }
        let dist = |p: &(f64, f64, Vec<f64>)| (x - p.0).abs().min((x - p.1).abs());
        let mut best = &self.pieces[0];
        for p in &self.pieces[1..] {
            if dist(p) < dist(best) {
                best = p;
            }
        }
        &best.2
    }

    /// The worst deviation (m) from y(x) of any bound covering road x, within x ± `half_range`
    /// (m): how far the lanes near x are from the straight lines nudge plans with.
    #[must_use]
    pub fn local_deviation(&self, x: f64, half_range: f64) -> f64 {
        let mut worst: f64 = 0.0;
        for p in &self.polylines {
            let (first, last) = (p[0][0], p[p.len() - 1][0]);
            if !(first <= x && x <= last) {
                continue;
            }
            let y0 = y_at(p, x);
            let ends = [
                (x - half_range).clamp(first, last),
                (x + half_range).clamp(first, last),
            ];
            let near = p
                .iter()
                .map(|q| q[0])
                .filter(|&px| (px - x).abs() <= half_range);
            for px in near.chain(ends) {
                worst = worst.max((y_at(p, px) - y0).abs());
            }
        }
        worst
    }
}
