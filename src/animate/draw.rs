//! Drawing one frame of a [`Reel`]: the road, the ego's executed path, the binding
//! vehicle's safety ellipses, the others' predicted reaction, every vehicle as its rotated
//! box, the plan, and the caption.

use embedded_graphics::Drawable;
use embedded_graphics::mono_font::MonoTextStyle;
use embedded_graphics::mono_font::ascii::FONT_6X10;
use embedded_graphics::prelude::{Point, Primitive, Size};
use embedded_graphics::primitives::{Circle, Line, Polyline, PrimitiveStyle, Rectangle, Triangle};
use embedded_graphics::text::{Baseline, Text};

use super::canvas::{Canvas, Ink};
use super::reel::{PlannedStep, Reel, Shot};
use super::view::{AnimationSettings, CAPTION_PX, View};

/// Dash and gap of the lane markings (m).
const DASH_M: [f64; 2] = [3.0, 6.0];
/// Objects whose centre lies further than this outside the frame (pixels) are not drawn.
const CULL_PX: f64 = 300.0;

/// Frame `k` of `reel` (`k < reel.shots.len()`, the reel validated) at `size` pixels
/// ([`super::frame_size`]) under `settings`.
#[must_use]
pub fn draw_frame(reel: &Reel, k: usize, settings: &AnimationSettings, size: (u32, u32)) -> Canvas {
    let shot = &reel.shots[k];
    let view = View::new(reel, settings, shot.agents[0][0]);
    let mut c = Canvas::new(size.0, size.1, Ink::Verge);
    road(&mut c, &view, reel);
    path(&mut c, &view, reel, k);
    let binding = shot.planned.as_ref().and_then(|p| p.binding.as_ref());
    if let Some(p) = &shot.planned {
        ellipses(&mut c, &view, p);
        predictions(&mut c, &view, shot, p);
    }
    for i in 1..shot.agents.len() {
        let ink = if binding.is_some_and(|b| b.agent == i) {
            Ink::Binding
        } else {
            Ink::Other
        };
        vehicle(&mut c, &view, shot.agents[i], reel.sizes[i], ink);
    }
    if let Some(p) = &shot.planned {
        plan(&mut c, &view, p);
    }
    let ego_ink = if shot.collision {
        Ink::Collision
    } else {
        Ink::Ego
    };
    vehicle(&mut c, &view, shot.agents[0], reel.sizes[0], ego_ink);
    caption(&mut c, reel, k);
    c
}

/// Whether the world point `p` (m) lies within [`CULL_PX`] of the frame horizontally.
fn near(c: &Canvas, view: &View, p: [f64; 2]) -> bool {
    let [x, y] = view.to_px(p);
    x > -CULL_PX
        && x < f64::from(c.width()) + CULL_PX
        && y > -CULL_PX
        && y < f64::from(c.height()) + CULL_PX
}

/// The part of the segment from `a` to `b` (continuous pixel coordinates) inside the frame
/// widened by 2 pixels (Liang–Barsky); `None` when none of it is, or a coordinate is not
/// finite. Clipping first keeps the work of a line proportional to its visible part, however
/// far away its ends lie.
#[must_use]
pub fn clip_segment(c: &Canvas, a: [f64; 2], b: [f64; 2]) -> Option<([f64; 2], [f64; 2])> {
    if !a.iter().chain(&b).all(|v| v.is_finite()) {
        return None;
    }
    let (lo, hi) = (
        [-2.0, -2.0],
        [f64::from(c.width()) + 2.0, f64::from(c.height()) + 2.0],
    );
    let (t0, t1) = nudge_planner::clip_segment_to_box(a, b, lo, hi)?;
    let at = |t: f64| [a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1])];
    Some((at(t0), at(t1)))
}

/// The road surface between its edges, the edges as solid lines and the inner lane
/// boundaries dashed (the dashes fixed to the road, so they move past the following camera).
fn road(c: &mut Canvas, view: &View, reel: &Reel) {
    let bounds = &reel.lane_bounds;
    let (lo, hi) = (bounds[0], bounds[bounds.len() - 1]);
    let top = view.point([view.x_left, hi]).y;
    let bottom = view.point([view.x_left, lo]).y;
    let band = Size::new(c.width(), u32::try_from(bottom - top).unwrap_or(0));
    let _ = Rectangle::new(Point::new(0, top), band)
        .into_styled(PrimitiveStyle::with_fill(Ink::Road))
        .draw(c);
    let shown_m = f64::from(c.width()) / view.px_per_m;
    let x_right = view.x_left + shown_m;
    let period = DASH_M[0] + DASH_M[1];
    let first = (view.x_left / period).floor() * period;
    // A count, not a distance: far from the origin, x + period may not move x at all.
    // In range: at most the frame's width in dashes.
    #[allow(clippy::cast_possible_truncation, clippy::cast_sign_loss)]
    let dashes = (shown_m / period).ceil().min(f64::from(c.width())) as u32 + 1;
    for &y in &bounds[1..bounds.len() - 1] {
        for k in 0..dashes {
            let x = first + f64::from(k) * period;
            line(c, view, [x, y], [x + DASH_M[0], y], Ink::Marking, 1);
        }
    }
    for y in [lo, hi] {
        line(c, view, [view.x_left, y], [x_right, y], Ink::Edge, 2);
    }
}

/// A line from `a` to `b` (m).
fn line(c: &mut Canvas, view: &View, a: [f64; 2], b: [f64; 2], ink: Ink, width: u32) {
    segment(c, view.to_px(a), view.to_px(b), ink, width);
}

/// A line between the continuous pixel coordinates `a` and `b`, clipped to the frame.
fn segment(c: &mut Canvas, a: [f64; 2], b: [f64; 2], ink: Ink, width: u32) {
    let Some((a, b)) = clip_segment(c, a, b) else {
        return;
    };
    // Clipped to the frame: the casts are exact.
    #[allow(clippy::cast_possible_truncation)]
    let pixel = |p: [f64; 2]| Point::new(p[0].round() as i32, p[1].round() as i32);
    let _ = Line::new(pixel(a), pixel(b))
        .into_styled(PrimitiveStyle::with_stroke(ink, width))
        .draw(c);
}

/// A polyline through the points `pts` (m).
fn polyline(c: &mut Canvas, view: &View, pts: &[[f64; 2]], ink: Ink, width: u32) {
    for w in pts.windows(2) {
        line(c, view, w[0], w[1], ink, width);
    }
}

/// A filled dot of `diameter` pixels centred on `p` (m), when near the frame.
fn dot(c: &mut Canvas, view: &View, p: [f64; 2], ink: Ink, diameter: u32) {
    if !near(c, view, p) {
        return;
    }
    let _ = Circle::with_center(view.point(p), diameter)
        .into_styled(PrimitiveStyle::with_fill(ink))
        .draw(c);
}

/// The ego's executed path: its positions in frames 0..=k.
fn path(c: &mut Canvas, view: &View, reel: &Reel, k: usize) {
    let pts: Vec<[f64; 2]> = reel.shots[..=k]
        .iter()
        .map(|s| [s.agents[0][0], s.agents[0][1]])
        .collect();
    polyline(c, view, &pts, Ink::Path, 2);
}

/// The corners (m) of a box of `size` = (length, width) (m) centred at (x, y) with heading
/// h (rad), `a` = (x, y, h): rear right, front right, front left, rear left.
#[must_use]
pub fn corners(a: [f64; 3], size: [f64; 2]) -> [[f64; 2]; 4] {
    let (s, co) = a[2].sin_cos();
    let (l, w) = (size[0] / 2.0, size[1] / 2.0);
    [[-l, -w], [l, -w], [l, w], [-l, w]]
        .map(|[u, v]| [a[0] + u * co - v * s, a[1] + u * s + v * co])
}

/// A vehicle `a` = (x, y, heading) (m, m, rad) of `size` (m) as its rotated box: filled with
/// `ink` (two triangles), outlined.
fn vehicle(c: &mut Canvas, view: &View, a: [f64; 3], size: [f64; 2], ink: Ink) {
    if !near(c, view, [a[0], a[1]]) {
        return;
    }
    let p = corners(a, size).map(|q| view.point(q));
    let fill = PrimitiveStyle::with_fill(ink);
    let _ = Triangle::new(p[0], p[1], p[2]).into_styled(fill).draw(c);
    let _ = Triangle::new(p[0], p[2], p[3]).into_styled(fill).draw(c);
    let outline = [p[0], p[1], p[2], p[3], p[0]];
    let _ = Polyline::new(&outline)
        .into_styled(PrimitiveStyle::with_stroke(Ink::Outline, 1))
        .draw(c);
}

/// The plan: a line through z_0..z_T with a dot at every planned state.
fn plan(c: &mut Canvas, view: &View, p: &PlannedStep) {
    let pts: Vec<[f64; 2]> = p.plan.iter().map(|z| [z[0], z[1]]).collect();
    polyline(c, view, &pts, Ink::Plan, 2);
    for q in &pts[1..] {
        dot(c, view, *q, Ink::Plan, 4);
    }
}

/// The others' predicted reaction to the plan: from each vehicle's position through its
/// predicted positions, a dot at each.
fn predictions(c: &mut Canvas, view: &View, shot: &Shot, p: &PlannedStep) {
    for (i, track) in p.predicted.iter().enumerate() {
        let a = shot.agents[i + 1];
        if !near(c, view, [a[0], a[1]]) {
            continue;
        }
        let mut pts = vec![[a[0], a[1]]];
        pts.extend(track.iter().copied());
        polyline(c, view, &pts, Ink::Predicted, 1);
        for q in track {
            dot(c, view, *q, Ink::Predicted, 3);
        }
    }
}

/// The binding vehicle's safety ellipses, one per plan step, centred on its predicted
/// position with semi-axes (a_x, a_y) along the road; the one at the binding step stronger.
fn ellipses(c: &mut Canvas, view: &View, p: &PlannedStep) {
    let Some(b) = &p.binding else {
        return;
    };
    let track = &p.predicted[b.agent - 1];
    for (k, (centre, axes)) in track.iter().zip(&b.semi_axes).enumerate() {
        let (ink, width) = if k == b.step {
            (Ink::Tight, 2)
        } else {
            (Ink::Ellipse, 1)
        };
        ellipse(c, view, *centre, *axes, ink, width);
    }
}

/// Vertices of a drawn ellipse.
const ELLIPSE_VERTICES: u32 = 96;

/// The axis-aligned ellipse centred on `centre` with semi-axes `axes` = (a_x, a_y) (m), as a
/// closed polygon of [`ELLIPSE_VERTICES`] clipped segments (its cost does not grow with its
/// size).
fn ellipse(c: &mut Canvas, view: &View, centre: [f64; 2], axes: [f64; 2], ink: Ink, width: u32) {
    let at = |k: u32| {
        let t = std::f64::consts::TAU * f64::from(k) / f64::from(ELLIPSE_VERTICES);
        view.to_px([centre[0] + axes[0] * t.cos(), centre[1] + axes[1] * t.sin()])
    };
    for k in 0..ELLIPSE_VERTICES {
        segment(c, at(k), at(k + 1), ink, width);
    }
}

/// Text `s` at column `x`, caption line `line` (0-based), in `ink`; returns the column after
/// it.
fn text(c: &mut Canvas, s: &str, x: i32, line: i32, ink: Ink) -> i32 {
    let style = MonoTextStyle::new(&FONT_6X10, ink);
    let at = Point::new(x, 3 + 11 * line);
    Text::with_baseline(s, at, style, Baseline::Top)
        .draw(c)
        .map_or(x, |p| p.x)
}

/// The caption band: the run's title; the step, plan status, speed, planning time and the
/// binding vehicle (or the end state); a colour key.
fn caption(c: &mut Canvas, reel: &Reel, k: usize) {
    let band = Size::new(c.width(), CAPTION_PX);
    let _ = Rectangle::new(Point::zero(), band)
        .into_styled(PrimitiveStyle::with_fill(Ink::Caption))
        .draw(c);
    // FONT_6X10: 6 pixels a character; what cannot show is not drawn.
    let fits = usize::try_from(c.width() / 6).unwrap_or(usize::MAX);
    let title: String = reel.title.chars().take(fits).collect();
    text(c, &title, 4, 0, Ink::Text);
    text(c, &step_line(reel, k), 4, 1, Ink::Text);
    let mut x = 4;
    for (s, ink) in [
        ("ego ", Ink::Ego),
        ("path ", Ink::Path),
        ("plan ", Ink::Plan),
        ("predicted reaction ", Ink::Predicted),
        ("binding vehicle ", Ink::Binding),
        ("its safety ellipses", Ink::Ellipse),
    ] {
        x = text(c, s, x, 2, ink) + 6;
    }
}

/// "step k/S  status  v … m/s  plan … ms  binds on vehicle i (b …)", or the end state.
#[must_use]
pub fn step_line(reel: &Reel, k: usize) -> String {
    let shot = &reel.shots[k];
    let steps = reel.shots.len() - 1;
    let crash = if shot.collision { "  COLLISION" } else { "" };
    let Some(p) = &shot.planned else {
        return format!(
            "end after {steps} steps  v {:.1} m/s{crash}",
            shot.ego_speed
        );
    };
    let binds = p.binding.as_ref().map_or_else(
        || "nothing checked".to_string(),
        |b| format!("binds on vehicle {} (b {:.2})", b.agent, b.b),
    );
    format!(
        "step {k}/{steps}  {}  v {:.1} m/s  plan {:.1} ms  {binds}{crash}",
        p.status.as_str(),
        shot.ego_speed,
        p.mpc_s * 1e3
    )
}
